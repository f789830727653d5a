"""Kalman/RTS smoothing of ground truth: velocities of known trajectories, tracks split at gaps and resets."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.calibration.lidar import stationary_spans
from pipeline.calibration.smoothing import SmootherNoise, smooth_track, smooth_trajectory

NS = 1_000_000_000


def circle(t_s: np.ndarray, speed: float = 0.3, yaw_rate: float = 0.2) -> np.ndarray:
    """Poses (n, 3) of a robot driving a circle from (1, 1) heading east."""
    r = speed / yaw_rate
    yaw = yaw_rate * t_s
    return np.stack([1 + r * np.sin(yaw), 1 + r * (1 - np.cos(yaw)), np.angle(np.exp(1j * yaw))], axis=1)


MOCAP = SmootherNoise(position_sigma_m=0.002, yaw_sigma_rad=0.004, accel_sigma_mps2=0.5, angular_accel_sigma_radps2=0.5)
"""A motion-capture system with 2 mm / 0.004 rad of noise tracking a smoothly moving robot."""


def test_smoothed_body_velocity_of_an_exact_circle_matches_its_speed_and_turn_rate():
    t = np.arange(0, 40, 0.02)
    track = smooth_track((t * NS).astype(np.int64), circle(t))
    body = track.body_velocity()[20:-20]
    np.testing.assert_allclose(body[:, 0], 0.3, atol=1e-4)
    np.testing.assert_allclose(body[:, 1], 0.2, atol=1e-4)


def test_smoothed_body_velocity_of_a_noisy_circle_is_unbiased():
    rng = np.random.default_rng(0)
    t = np.arange(0, 40, 0.02)
    pose = circle(t) + rng.normal(0, [0.002, 0.002, 0.004], size=(len(t), 3))
    track = smooth_track((t * NS).astype(np.int64), pose, MOCAP)
    body = track.body_velocity()[50:-50]  # away from the ends, where the smoother sees one side only
    assert np.abs(body[:, 0] - 0.3).max() < 0.03
    assert np.abs(body[:, 1] - 0.2).max() < 0.03
    assert abs(body[:, 0].mean() - 0.3) < 0.002 and abs(body[:, 1].mean() - 0.2) < 0.002
    # the yaw is unwrapped across +-pi (the circle turns 8 rad)
    assert track.pose[-1, 2] == pytest.approx(8.0 - 0.02 * 0.2, abs=0.02)


def test_lost_messages_are_bridged_and_any_time_can_be_asked():
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.02)
    keep = rng.random(len(t)) > 0.2
    track = smooth_track((t[keep] * NS).astype(np.int64), circle(t[keep]))
    query = np.arange(1.01, 19.0, 0.1)
    pose, vel = track.at((query * NS).astype(np.int64))
    np.testing.assert_allclose(pose[:, :2], circle(query)[:, :2], atol=1e-3)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    np.testing.assert_allclose(speed, 0.3, atol=0.01)


def test_a_standing_robot_has_zero_velocity_despite_noise():
    rng = np.random.default_rng(2)
    t = np.arange(0, 5, 0.02)
    pose = np.tile([2.0, 1.0, 3.1], (len(t), 1)) + rng.normal(0, [0.002, 0.002, 0.004], size=(len(t), 3))
    track = smooth_track((t * NS).astype(np.int64), pose, MOCAP)
    assert np.abs(track.velocity[:, :2]).max() < 0.02
    assert np.abs(track.velocity[:, 2]).max() < 0.03
    # averaged over half a second the noise no longer looks like motion (except near the ends)
    spans = stationary_spans(track, speed_mps=0.005, yaw_rate_radps=0.01, min_s=1.0)
    assert sum(b - a for a, b in spans) / NS > 0.8 * track.duration_s


def test_gaps_resets_and_windows_split_tracks():
    t = np.arange(0, 10, 0.02)
    pose = circle(t)
    pose[250:, 0] += 2.0  # a reset teleports the robot
    times = (t * NS).astype(np.int64)
    times[400:] += 2 * NS  # a 2 s gap
    traj = smooth_trajectory(times, pose)
    assert [len(tr.t_ns) for tr in traj.tracks] == [250, 150, 100]
    windows = [(0, int(3 * NS)), (int(6 * NS), int(20 * NS))]
    traj = smooth_trajectory(times, pose, windows=windows)
    for tr in traj.tracks:
        assert tr.end_ns <= windows[0][1] or tr.start_ns >= windows[1][0]
    # nothing is reported between tracks
    pose_at, _ = traj.at(np.array([int(3.5 * NS)]))
    assert np.isnan(pose_at).all()
    assert traj.track_index(np.array([int(1 * NS), int(3.5 * NS)])).tolist() == [0, -1]
