"""Calibration against the hardware twin: every estimate lands near the reality profile the twin played.

Each bundled profile (mild, harsh) drives one deployment session of the excitation controller over
DDS on loopback at time scale 2 (8 episodes of 12 s of twin time). The profile file is read here
only, as ground truth; the calibration sees the recording alone. The lab profile plays at time scale
1, on the host's own clock, as a real fleet does: the robots' clock offset is then bounded, and the
drift is measured against a clock that does not wander with the host's load.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import yaml
from calibration_coverage import realized_jitter
from drive_replay import replay_drive, replayed_tracks

from pipeline.calibration import PROFILE_KEYS, Calibration, CalibrationSettings, calibrate, write_calibration
from pipeline.calibration.actuation import estimate_actuation
from pipeline.calibration.calibrate import drive_record
from pipeline.calibration.localize import OccupancyMap
from pipeline.core.scenario import load_scenario
from pipeline.params import WorldConfig, calibrated_world
from pipeline.twin.profile import load_profile
from tests.calibration_helpers import TWIN_STEPS, link_record_of, record_twin_session

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


class Tolerance(NamedTuple):
    """|estimate - truth| <= abs + rel * |truth|, for the reason given."""

    abs: float
    rel: float
    reason: str


TOLERANCES: dict[str, Tolerance] = {
    "lidar.beams": Tolerance(0, 0, "read from the scans' length"),
    "lidar.rate_hz": Tolerance(0, 0.03, "median gap of the stamped ticks; a stalled host stretches the twin's ticks"),
    "lidar.noise_sigma_m": Tolerance(
        0, 0.10, ">= 20 000 residuals: bootstrap SE about 0.5 %; room for the clip correction and truth-pose errors"
    ),
    "lidar.dropout_prob": Tolerance(0.002, 0.2, "binomial over >= 20 000 beams: SE 3 % of p at 0.05, 8 % at 0.01"),
    "lidar.bias_m": Tolerance(
        0.006,
        0,
        "fitted jointly with the walls' offset (a range bias on wall beams looks like walls further out): SE 2 mm",
    ),
    "lidar.mount_yaw_rad": Tolerance(
        0.003, 0, "SE about 0.0002 rad over thousands of oblique beams; a sixth of the 1 degree beam spacing"
    ),
    "actuation.delay_s": Tolerance(
        0.035,
        0,
        "commands act when the twin receives them: the apparent delay is the profile's plus the DDS latency and the "
        "wheel servos' own response (a few ms to 20 ms of twin time at scale 3), less the emitter grid's phase",
    ),
    "actuation.time_constant_s": Tolerance(
        0,
        0.2,
        "MuJoCo's implicit velocity servo at 5 ms steps lengthens the lag (+1-2 %); the smoother's bandwidth and "
        "the twin's irregular ticks blur the steps (+5-10 % measured); tau trades off against the delay's 20 ms",
    ),
    "actuation.linear_gain": Tolerance(
        0,
        0.05,
        "SE 0.5-1 %; the replay's smoothing and the time-scaled twin's irregular ticks (its physics catches up a "
        "host stall step by step, and its sensors are published late) leave a few tenths of a percent",
    ),
    "actuation.angular_gain": Tolerance(0, 0.05, "as the linear gain"),
    "odometry.rate_hz": Tolerance(0, 0.03, "as the lidar's rate"),
    "odometry.drift_per_m": Tolerance(
        0, 0.35, "spread of n = 35-70 per-episode draws: relative SE 1/sqrt(2n) = 8-12 %, 35 % is about 3 SE"
    ),
    "network.loss_prob": Tolerance(
        0.005,
        0.3,
        "isolated losses among ~20 000 messages: SE 3 % of p at 0.1; a busy host also drops single messages at "
        "the receiver (+0.3 % absolute measured)",
    ),
    "lidar.noise_per_m": Tolerance(0.0015, 0.2, "a line through the within-span spread in 0.5 m range bins"),
    "lidar.range_step_m": Tolerance(1e-5, 0, "continuous ranges: no lattice of 10 um or more"),
    "lidar.beam_noise_spread": Tolerance(
        0.12,
        0,
        "the same noise on every beam, but beams whose returns move within a still span (a robot still to the "
        "smoother, not to a grazing beam) read as uneven noise: 0.02-0.06 on these sessions, up to +0.1 on the "
        "coverage benchmark's realities (docs/lidar.md)",
    ),
    "lidar.mixed_pixel_prob": Tolerance(0.03, 0, "no mixed pixels: returns at depth edges lie on their surfaces"),
    "lidar.rate_wander": Tolerance(0.002, 0, "a steady sweep, stamped at its start on the twin's clock"),
    "lidar.scan_drop_prob": Tolerance(
        0.02,
        0,
        "no scan lost in the driver, but the scan topics read a higher loss than the others on these sessions "
        "(+1.5 % on harsh, whose link loses 10 %; the cause, in the twin's link or in the loss estimate, not found)",
    ),
    "base.wheel_radius_left_m": Tolerance(
        0,
        0.03,
        "odometry against truth; these profiles' odometry errors (0.04-0.08 per m, drawn per robot-episode as "
        "scale and yaw-scale errors) move each episode's apparent wheels by that much: 24 robot-episodes leave "
        "the mean within about 3 SE of 1.6 %",
    ),
    "base.wheel_radius_right_m": Tolerance(0, 0.03, "as the left wheel"),
    "base.wheel_separation_m": Tolerance(
        0, 0.1, "from the turns only, where the harsh profile's yaw-scale errors (8 % per robot-episode) act"
    ),
    "clock.drift_ppm": Tolerance(
        120.0, 0, "slope of the delay envelope over about 100 s of twin time: 120 ppm is 12 ms over it"
    ),
    "map.wall_offset_m": Tolerance(0.004, 0, "beams on the walls from every stationary span: SE about 1 mm"),
    "base.deadband_radps": Tolerance(0.1, 0, "no deadband in the profile: within two 0.05 rad/s grid steps of 0"),
    "network.burst_len": Tolerance(0, 0.3, "missing / runs of missing messages: independent losses give about 1"),
    "base.motor_time_constant_s": Tolerance(
        0.03,
        0,
        "no motor lag in these profiles: the transients' grid puts a twelfth of the total lag per share step, so the "
        "motors' share reads within a step or two of 0 (or the transients leave it open: unidentifiable)",
    ),
    "network.jitter_s": Tolerance(
        0.003,
        0.3,
        "scored against the jitter the twin's link realized on the run (its --link-record read by calibration's pair "
        "rule at the sender): a twin on a busy host adds its own scheduling to the profile's, which at time scale 2 "
        "is 2.5-10 ms of wall-clock time; against the profile the estimate read 16 ms for 5 (mild) and 45 ms for 20 "
        "(harsh) beside a busy suite; an estimate of 0 fails both profiles",
    ),
}


@pytest.fixture(scope="session", params=["mild", "harsh"])
def twin_calibration(request: pytest.FixtureRequest, twin_session):
    """(profile name, the profile as the twin read it, the calibration of one recorded session)."""
    name = request.param
    recording = twin_session(name)
    truth = with_ideal_defaults(yaml.safe_load((ROOT / "pipeline" / "twin" / "profiles" / f"{name}.yaml").read_text()))
    realized = realized_jitter(link_record_of(recording))
    assert realized is not None, "the twin's link record has no two sensor topics"
    truth["network"]["jitter_s"] = realized  # what the link did on this run, the profile's value beside it
    return name, truth, calibrate(recording, CalibrationSettings(bootstrap=100))


def with_ideal_defaults(truth: dict) -> dict:
    """The profile with its optional keys at the ideal values the twin takes when they are absent."""
    ideal = {
        "lidar": {
            "noise_per_m": 0.0,
            "range_step_m": 0.0,
            "beam_noise_spread": 0.0,
            "mixed_pixel_prob": 0.0,
            "rate_wander": 0.0,
            "scan_drop_prob": 0.0,
        },
        "base": {
            "wheel_radius_left_m": 0.034,
            "wheel_radius_right_m": 0.034,
            "wheel_separation_m": 0.281,
            "deadband_radps": 0.0,
            "motor_time_constant_s": 0.0,
        },
        "clock": {"offset_s": 0.0, "drift_ppm": 0.0},
        "map": {"wall_offset_m": 0.0},
        "network": {"burst_len": 1.0},
    }
    return {g: {**ideal.get(g, {}), **truth.get(g, {})} for g in {*ideal, *truth}}


MAY_BE_UNIDENTIFIED = {"base.motor_time_constant_s": "part of effective.drive_lag_s"}
"""Keys these profiles leave at zero, which the data may read near zero or leave open, with the word that says so."""
UNIDENTIFIABLE_ON_THE_TWIN = {
    "clock.offset_s": "/clock",
    "base.max_wheel_accel_radps2": "no limit binds",
    "base.friction": "friction is",
    "lidar.beam_angle_jitter_rad": "grazing",
}
"""Keys the mild and harsh recordings cannot tell, and a word their reason must name: the clock offset on a
time-scaled twin, an acceleration limit these profiles do not have, and the floor's friction (never identified: the
recording does not give the weight on the driven wheels; the reason bounds it)."""


def test_the_tolerance_table_covers_every_profile_key():
    every = {f"{group}.{key}" for group, keys in PROFILE_KEYS.items() for key in keys}
    assert set(TOLERANCES) | set(UNIDENTIFIABLE_ON_THE_TWIN) == every


EFFECTIVE_KEYS = {"actuation.delay_s": "drive_delay_s", "actuation.time_constant_s": "drive_lag_s"}
"""Profile keys the body velocity measures only with the motors' lag: the effective value stands for them, and its
truth is the sum of what it stands for (the profiles here have no acceleration limit)."""


def truth_of_effective(truth: dict, keys: tuple[str, ...]) -> float:
    return sum(float(truth[g][f] or 0.0) for g, f in (k.split(".") for k in keys) if not f.startswith("max_wheel"))


@pytest.mark.alone  # beside a second worker: the jitter read 10-16 ms for 5 ms, the linear gain 0.755 for 0.8
def test_every_estimate_lies_within_its_tolerance_of_the_profile(twin_calibration):
    name, truth, result = twin_calibration
    misses = []
    print(f"\nprofile {name}: {'key':26s} {'profile':>9s} {'estimate':>10s} {'std err':>9s} {'allowed':>8s}")
    for key, tol in TOLERANCES.items():
        group, field = key.split(".")
        est = result.values[key]
        expected = float(truth[group][field])
        if key in EFFECTIVE_KEYS:
            # the body velocity's delay and lag are the simulator's effective values, scored against what they
            # stand for; the profile key is the wheels' reading of the driver, or unidentified naming the effective
            effective = result.effective[EFFECTIVE_KEYS[key]]
            if not est.ok and f"effective.{EFFECTIVE_KEYS[key]}" not in est.reason:
                misses.append(f"{key}: neither read at the wheels nor pointing to its effective value: {est}")
            wheels = est.interval if est.ok else None
            if wheels is not None and not wheels[0] - tol.abs <= expected <= wheels[1] + tol.abs + tol.rel * expected:
                misses.append(f"{key}: at the wheels {est.value} {wheels}, profile {expected:.4g}")
            est, expected = effective.estimate, truth_of_effective(truth, effective.stands_for)
        if not est.ok or est.value is None:
            if key not in MAY_BE_UNIDENTIFIED or MAY_BE_UNIDENTIFIED[key] not in est.reason:
                misses.append(f"{key}: unidentifiable ({est.reason})")
            continue
        allowed = tol.abs + tol.rel * abs(expected)
        se = est.std_error if est.std_error is not None else float("nan")
        print(f"profile {name}: {key:26s} {expected:9.4g} {est.value:10.4g} {se:9.2g} {allowed:8.3g}")
        if abs(est.value - expected) > allowed + 1e-12:
            misses.append(f"{key}: {est.value:.5g}, profile {expected:.5g}, allowed +-{allowed:.3g} ({tol.reason})")
    for key, word in UNIDENTIFIABLE_ON_THE_TWIN.items():
        if result.values[key].ok or word not in result.values[key].reason:
            misses.append(f"{key}: expected unidentifiable, naming {word!r}: {result.values[key]}")
    assert not misses, f"profile {name}:\n" + "\n".join(misses)


@pytest.mark.alone
def test_the_calibration_file_trains_the_simulator_toward_the_profile(twin_calibration, tmp_path):
    name, truth, result = twin_calibration
    assert isinstance(result, Calibration) and result.sources[0].session["profile"] == name
    path = write_calibration(result, tmp_path)
    data = yaml.safe_load(path.read_text())
    # boxes that few beams see from the stationary spans of short episodes may stay unidentified; nothing else
    expected = ("map.box_offsets_m[", *UNIDENTIFIABLE_ON_THE_TWIN, *EFFECTIVE_KEYS, *MAY_BE_UNIDENTIFIED)
    assert all(key.startswith(expected) for key in data["unidentified"]), data["unidentified"]
    assert {"lidar", "actuation", "odometry", "network", "base", "clock", "map"} == set(data["profile"])
    world = calibrated_world(WorldConfig(), path)
    assert world.lidar.sim_beams == truth["lidar"]["beams"] and world.lidar.robot_radius_seen_m == 0.0
    assert world.lidar.noise_sigma_m == pytest.approx(truth["lidar"]["noise_sigma_m"], rel=0.1)
    assert world.actuation.linear_gain == pytest.approx(truth["actuation"]["linear_gain"], rel=0.05)
    for plot in ("lidar_residuals.png", "lidar_mount_yaw.png", "actuation_fit.png", "odometry_drift.png"):
        assert (tmp_path / plot).stat().st_size > 10_000
        assert f"]({plot})" in (tmp_path / "calibration.md").read_text()


LAB_TOLERANCES: dict[str, Tolerance] = {
    "lidar.noise_sigma_m": Tolerance(0, 0.15, "within-span spread; the issue's 15 %"),
    "lidar.noise_per_m": Tolerance(0, 0.15, "slope of the spread over range bins"),
    "lidar.dropout_prob": Tolerance(0, 0.15, "the mast's sector left out, the rest binomial"),
    "lidar.bias_m": Tolerance(0.002, 0, "fitted with the walls' and boxes' true places"),
    "lidar.mount_yaw_rad": Tolerance(0.003, 0, "Gauss-Newton over thousands of oblique beams"),
    "lidar.mount_xy_m[0]": Tolerance(0, 0.15, "the beams' origin 5 cm ahead of the axle"),
    "lidar.mount_xy_m[1]": Tolerance(0.005, 0, "no sideways offset: within 5 mm of 0"),
    "base.wheel_radius_left_m": Tolerance(0, 0.01, "odometry against truth"),
    "base.wheel_radius_right_m": Tolerance(0, 0.01, "odometry against truth"),
    "base.wheel_separation_m": Tolerance(0, 0.02, "odometry against truth, from the turns"),
    "clock.drift_ppm": Tolerance(
        120.0, 0, "slope of the delay envelope over about 70 s: 40 ppm is 3 ms against ms of delivery jitter"
    ),
    "clock.offset_s": Tolerance(0.012, 0, "bounded by the quickest delivery, assumed within 10 ms"),
    "map.wall_offset_m": Tolerance(0.004, 0, "beams on the walls"),
    "base.deadband_radps": Tolerance(0.1, 0, "held commands below and above 0.6 rad/s: two 0.05 rad/s grid steps"),
    "base.max_wheel_accel_radps2": Tolerance(0, 0.15, "transients of the wheel speeds; the issue's 15 %"),
}


@pytest.fixture(scope="session")
def lab_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_twin_session(tmp_path_factory.mktemp("twin_lab"), "lab", 6, time_scale=1.0, max_steps=TWIN_STEPS)


@pytest.fixture(scope="session")
def lab_calibration(lab_recording: Path):
    truth = yaml.safe_load((ROOT / "pipeline" / "twin" / "profiles" / "lab.yaml").read_text())
    return truth, calibrate(lab_recording, CalibrationSettings(bootstrap=100))


def test_the_lab_reality_is_calibrated_where_it_is_identifiable(lab_calibration):
    """The lab SPARK is not the simulator (wheel contacts, two lags, deadband, acceleration limit, moved room):
    every key the recording can tell lies within the issue's 15 % (or an absolute margin where the truth is
    small), the mast's sector is found, and the boxes' true places are recovered where enough beams see them."""
    truth, result = lab_calibration
    misses = []
    for key, tol in LAB_TOLERANCES.items():
        group, _, rest = key.partition(".")
        expected = (
            float(truth[group]["mount_xy_m"][int(rest[-2])])
            if rest.startswith("mount_xy_m")
            else float(truth[group][rest])
        )
        est = result.values[key]
        if not est.ok or est.value is None:
            misses.append(f"{key}: unidentifiable ({est.reason})")
        elif abs(est.value - expected) > tol.abs + tol.rel * abs(expected) + 1e-12:
            misses.append(f"{key}: {est.value:.5g}, profile {expected:.5g} ({tol.reason})")
    assert not misses, "\n".join(misses)
    (sector,) = result.lidar.blocked_sectors_rad
    assert sector[0] == pytest.approx(2.9, abs=0.03) and sector[1] == pytest.approx(3.38, abs=0.03)
    boxes = [(b, i) for b in range(2) for i in range(2) if result.values[f"map.box_offsets_m[{b}][{i}]"].ok]
    for b, i in boxes:
        assert result.values[f"map.box_offsets_m[{b}][{i}]"].value == pytest.approx(
            truth["map"]["box_offsets_m"][b][i], abs=0.006
        )


def test_the_lab_lidar_s_absent_artefacts_are_not_read_into_it(lab_calibration):
    """The lab's lidar has one noise for every beam and no mixed pixels, while the other robots drive through the
    still robots' beams and stand in front of box corners: the mixed pixels' interval holds 0 (a robot standing at
    a depth edge is no mixed pixel), and the beams' spread reads under 0.05 (a passing robot's returns no longer move
    a beam's mean, each deviation is scaled by the noise at its own range: it read 0.07-0.11 before). The spread is
    bounded rather than its interval asked to hold 0: a 95 % interval misses a true 0 in one recording of twenty by
    construction. So are the mixed pixels, and what the calibrated world takes of them is held: a reading whose
    interval leaves out 0 is weak (it stays out of the world), as one recording beside a second worker read 0.0015
    [0.00026, 0.011]."""
    _, result = lab_calibration
    mixed = result.values["lidar.mixed_pixel_prob"]
    assert mixed.interval is not None and (mixed.interval[0] == 0.0 or not mixed.ok), mixed
    assert mixed.value is not None and mixed.value < 0.005, mixed
    spread = result.values["lidar.beam_noise_spread"]
    assert spread.value is not None and spread.value < 0.05, spread


def test_the_lab_drive_replayed_is_what_its_effective_values_stand_for(lab_recording, lab_calibration):
    """The lab's drive (a driver's delay and lag, motors that lag, a deadband, an acceleration limit) is not the
    simulator's one-lag model. Replayed noise-free under the recording's commands through the lab profile's own
    drive, the bodies move as recorded; the simulator's model fitted to that replay (what each effective drive value
    stands for) lies inside calibration's intervals, while the driver's own delay does not."""
    _, result = lab_calibration
    settings = CalibrationSettings(bootstrap=100)
    record = drive_record(lab_recording, settings)
    _, profile = load_profile("lab")
    replayed = replay_drive(record.sessions[0], profile)
    recorded = np.concatenate([t.achieved[:, 0] for t in record.tracks])
    again = np.concatenate([replayed[t.robot].at(t.t_ns)[0][:, 0] for t in record.tracks])
    moving = np.abs(recorded) > 0.05
    assert moving.sum() > 500
    assert np.median(np.abs(again - recorded)[moving]) < 0.1 * np.median(np.abs(recorded[moving]))
    fit = estimate_actuation(replayed_tracks(record.tracks, replayed), settings, np.random.default_rng(0))
    stands_for = {
        "drive_delay_s": (result.effective["drive_delay_s"].estimate, fit.delay_s),
        "drive_lag_s": (result.effective["drive_lag_s"].estimate, fit.time_constant_s),
        "drive_response_s": (result.effective["drive_response_s"].estimate, fit.response_s),
        "linear_gain": (result.values["actuation.linear_gain"], fit.linear_gain),
        "angular_gain": (result.values["actuation.angular_gain"], fit.angular_gain),
    }
    for name, (estimate, truth) in stands_for.items():
        assert estimate.ok and truth.ok and estimate.interval is not None, name
        lo, hi = estimate.interval
        assert lo <= truth.value <= hi, f"{name}: replayed {truth.value:.4g} outside [{lo:.4g}, {hi:.4g}]"
    lo, hi = result.effective["drive_delay_s"].estimate.interval
    assert not lo <= profile.actuation.delay_s <= hi  # the chain's effective delay is not the driver's


def test_a_stall_the_twin_jumped_freezes_the_replay_as_it_froze_the_twin(lab_recording):
    """A host stall the twin jumped over (its record's `jump_ns`, `jump_skipped_ns`) stood its world still; the
    replay stands still through it too and takes up the commands after it, so what the drive keys are scored against
    is the motion the twin realized."""
    import dataclasses

    record = drive_record(lab_recording, CalibrationSettings(bootstrap=10))
    session = record.sessions[0]
    session = dataclasses.replace(session, episodes=session.episodes[:1])
    _, profile = load_profile("lab")
    at, skipped = session.episodes[0].start_ns + 3_000_000_000, 1_000_000_000
    plain = replay_drive(session, profile)
    frozen = replay_drive(session, profile, jumps=[(at, skipped)])
    name = session.robots[0].name
    t, a, b = plain[name].t_ns, plain[name].velocity, frozen[name].velocity
    before, inside, after = t <= at, (t > at) & (t <= at + skipped), t > at + skipped
    assert np.array_equal(a[before], b[before])
    assert np.abs(b[inside] - b[inside][0]).max() == 0.0  # the bodies stood as they were
    assert np.abs(a[before][-1]).max() > 0.05  # moving when the world froze
    assert np.abs(a[inside] - b[inside]).max() > 0.01 and not np.array_equal(a[after], b[after])


WITHOUT_TRUTH_UNIDENTIFIABLE = (
    "lidar.mount_yaw_rad",
    "lidar.mount_xy_m[0]",
    "lidar.mount_xy_m[1]",
    "lidar.bias_m",
    "map.wall_offset_m",
)
"""Keys that poses localized from the scans cannot tell: the mounting moves the localized pose with it; a range
bias and a wall offset both read as a larger room (measured on the lab: 0.023 and -0.001 m without ground truth,
0.010 and 0.015 with, truth 0.01 and 0.015; their sums agree)."""


def test_the_lab_calibrates_without_motion_capture(lab_recording, lab_calibration, tmp_path):
    """/ground_truth left out: each robot is localized from its scans and odometry in the room written as a
    map_server occupancy grid (as a SLAM tool would), and every key the ground-truth calibration identified lies
    within 15 % of its value (plus the key's absolute margin from the table). Measured with the scenario's own
    walls and boxes as the map too: the same keys pass (tests/unit/test_calibration_localize.py covers that map)."""
    _, with_truth = lab_calibration
    floor = OccupancyMap.from_scenario(load_scenario("obstacles")).write_map_server(tmp_path / "floor.yaml")
    settings = CalibrationSettings(bootstrap=100, pose_source="scans", map_file=str(floor))
    without = calibrate(lab_recording, settings)
    assert without.pose_source.kind == "localized" and without.pose_source.median_score > 0.8
    misses = []
    for key, tol in LAB_TOLERANCES.items():
        a, b = with_truth.values[key], without.values[key]
        if key in WITHOUT_TRUTH_UNIDENTIFIABLE:
            assert not b.ok, key
            continue
        if not a.ok:
            continue
        if not b.ok or b.value is None:
            misses.append(f"{key}: unidentifiable without ground truth ({b.reason})")
        elif abs(b.value - a.value) > 0.15 * abs(a.value) + tol.abs + 1e-12:
            misses.append(f"{key}: {b.value:.5g} without ground truth, {a.value:.5g} with")
    assert not misses, "\n".join(misses)


def test_the_lab_gains_read_at_the_body_and_at_the_wheels_are_reconciled(lab_calibration, tmp_path):
    """The lab's deadband makes the body-velocity fit read smaller gains than the wheels' chain. Run over the
    recorded commands, the wheel chain's gains with the deadband must move the body as the body-velocity fit read
    it; the simulator takes the gains that do so exactly (near the wheel chain's, which agree), and calibration.yaml,
    calibration.md and the command's lines say so with one value."""
    _, result = lab_calibration
    agreements = {a.channel: a for a in result.gain_agreement()}
    assert agreements, "the lab's deadband is identified: both readings exist"
    for channel, agreement in agreements.items():
        assert agreement.agrees, agreement.sentence()
        assert agreement.with_deadband <= agreement.wheel_chain + 1e-12, channel  # the deadband takes speed away
    # turns are where the lab's 0.6 rad/s deadband holds wheels still: the angular gain drops by more than 5 %
    assert agreements["angular"].with_deadband < 0.95 * agreements["angular"].wheel_chain
    assert "the deadband accounts for" in agreements["angular"].sentence()
    for channel, agreement in agreements.items():
        assert result.world_overrides()["actuation"][f"{channel}_gain"] == pytest.approx(agreement.simulator, 1e-5)
    simulator = result.simulator_gains()
    fitted = (result.values["actuation.linear_gain"].value, result.values["actuation.angular_gain"].value)
    assert simulator is not None and result.drive_gains == simulator
    assert result.deadband_gains is not None and simulator[1] > fitted[1]  # the deadband's share given back
    folder = tmp_path / "out"
    write_calibration(result, folder)
    written = yaml.safe_load((folder / "calibration.yaml").read_text())["gains"]
    report = (folder / "calibration.md").read_text()
    for channel, agreement in agreements.items():
        assert written[channel]["wheel_chain_with_deadband"] == pytest.approx(agreement.with_deadband, rel=1e-5)
        assert written[channel]["simulator"] == pytest.approx(agreement.simulator, rel=1e-5)
        assert written[channel]["agrees"] is True
        assert agreement.sentence() in report
