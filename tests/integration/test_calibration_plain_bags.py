"""A plain ROS 2 bag of a twin deployment (standard topics only) calibrates like the full recording.

Each bundled profile (mild, harsh) drives one deployment session of the excitation controller
against the hardware twin over DDS on loopback: the recording test_calibration_twin.py calibrates
(tests/integration/conftest.py::twin_session, 8 episodes of 12 s of twin time at time scale 2). Its
rosbag2 copy keeps the robots' topics only: no /mrl/episode, no metadata. The twin redraws every
robot's odometry errors at each reset, so the bag's episodes must be found from the resets in its
poses; calibrating it as one episode averages the draws of all episodes and shrinks drift_per_m by
about 1/sqrt(8).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import pytest
import yaml

from pipeline.calibration import CalibrationSettings, calibrate
from pipeline.calibration.recording import read_session
from tests.calibration_helpers import TWIN_EPISODES
from tests.integration.test_calibration_inputs import rosbag2_copy
from tests.integration.test_calibration_twin import (
    EFFECTIVE_KEYS,
    TOLERANCES,
    truth_of_effective,
    with_ideal_defaults,
)

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
DRIFT_REL = 0.15
"""The bag's drift_per_m against the full recording's: the same draws, cut at the resets, not the episode events."""


class PlainBag(NamedTuple):
    name: str
    profile: dict[str, dict[str, float]]
    recording: Path
    bag: Path


@pytest.fixture(scope="session", params=["mild", "harsh"])
def plain_bag(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory, twin_session) -> PlainBag:
    """A twin deployment of one profile and its standard-topics-only rosbag2 copy."""
    name = request.param
    folder = tmp_path_factory.mktemp(f"plain_{name}")
    recording = twin_session(name)
    profile = with_ideal_defaults(
        yaml.safe_load((ROOT / "pipeline" / "twin" / "profiles" / f"{name}.yaml").read_text())
    )
    return PlainBag(name, profile, recording, rosbag2_copy(recording, folder / "bag"))


def test_the_bag_is_split_at_the_resets_between_the_recorded_episodes(plain_bag):
    recorded = read_session(plain_bag.recording, ["odometry"]).episodes
    data = read_session(plain_bag.bag, ["odometry"], "obstacles")
    assert not data.has_episode_topic and f"inferred from {TWIN_EPISODES - 1} reset(s)" in data.notes[0]
    inferred = data.episodes
    assert len(inferred) == len(recorded) == TWIN_EPISODES
    for k in range(1, TWIN_EPISODES):
        # the reset follows the end event: the bag's episode ends with the last pose before it and
        # the next begins before the next start event. Slack: the last poses before a reset can be
        # lost (or stalled, on a busy host: gaps of 0.3 s of twin time seen at time scale 5)
        assert recorded[k - 1].end_ns - 400_000_000 <= inferred[k - 1].end_ns < inferred[k].start_ns
        assert inferred[k].start_ns <= recorded[k].start_ns


@pytest.mark.alone  # the twin tests' lidar and drive tolerances (alone there: a recording beside a second worker)
def test_the_bag_calibrates_to_the_drift_of_the_full_recording_and_the_profile(plain_bag):
    name, profile = plain_bag.name, plain_bag.profile
    full = calibrate(plain_bag.recording, CalibrationSettings(bootstrap=50, parts=("odometry", "network")))
    bag = calibrate(plain_bag.bag, CalibrationSettings(bootstrap=50, scenario="obstacles"))
    drift, full_drift = bag.values["odometry.drift_per_m"], full.values["odometry.drift_per_m"]
    print(f"\nprofile {name}: drift_per_m bag {drift.value:.4g} {drift.interval}, full {full_drift.value:.4g}")
    assert drift.ok and full_drift.ok and drift.value is not None and full_drift.value is not None
    # the same robot-episodes give (nearly) the same draws: the bag's windows also hold the waits for the
    # resets, so a robot-episode can just pass or miss the turn needed for its yaw-scale draw
    assert abs(drift.n - full_drift.n) <= max(2, full_drift.n // 10)
    assert drift.value == pytest.approx(full_drift.value, rel=DRIFT_REL)
    # 24 robot-episodes, 60-70 draws: the 95 % chi interval is about +-20 %; it holds the profile's value
    true_drift = profile["odometry"]["drift_per_m"]
    assert drift.interval is not None and drift.interval[0] <= true_drift <= drift.interval[1]
    for key in ("network.loss_prob", "network.jitter_s"):
        # the same messages in slightly other windows (the bag's hold the waits for the resets too)
        ours, theirs = bag.values[key], full.values[key]
        assert ours.value is not None and theirs.value is not None
        allowed = 2 * max(ours.std_error or 0.0, theirs.std_error or 0.0)
        assert abs(ours.value - theirs.value) <= allowed, f"{key}: {ours.value:.4g}, full {theirs.value:.4g}"
    misses = []
    for key, tol in TOLERANCES.items():
        group, field = key.split(".")
        if group not in ("lidar", "actuation"):
            continue
        est, expected = bag.values[key], float(profile[group][field])
        if key in EFFECTIVE_KEYS:  # the drive's delay and lag: the simulator's effective values
            effective = bag.effective[EFFECTIVE_KEYS[key]]
            est, expected = effective.estimate, truth_of_effective(with_ideal_defaults(profile), effective.stands_for)
        if not est.ok or est.value is None or abs(est.value - expected) > tol.abs + tol.rel * abs(expected) + 1e-12:
            misses.append(f"{key}: {est.value}, profile {expected:.5g} ({tol.reason})")
    assert not misses, f"profile {name}:\n" + "\n".join(misses)
