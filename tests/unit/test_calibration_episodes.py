"""Episodes of a recording without /mrl/episode, inferred from the resets seen in its poses."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from pipeline.calibration.recording import (
    MessageTimes,
    PoseJump,
    PoseSeries,
    infer_episodes,
    pose_jumps,
    reset_boundaries,
)

NS = 1_000_000_000
TICK_NS = 20_000_000
STARTS = np.array([[1.0, 1.0, 0.0], [3.0, 1.0, 1.5], [2.0, 3.0, -2.0]])


def series(t_ns: np.ndarray, pose: np.ndarray) -> PoseSeries:
    t = np.asarray(t_ns, dtype=np.int64)
    return PoseSeries(MessageTimes(t, t, t, 0), np.asarray(pose, dtype=np.float64))


def straight(n: int, speed_mps: float, dt_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    t = (np.arange(n) * dt_s * NS).astype(np.int64)
    pose = np.zeros((n, 3))
    pose[:, 0] = speed_mps * dt_s * np.arange(n)
    return t, pose


def test_driving_at_full_speed_is_not_a_jump():
    t, pose = straight(200, 0.5)
    pose[:, 2] = np.angle(np.exp(1j * (3.1 + 0.03 * np.arange(200))))  # turning through +-pi
    assert len(pose_jumps(t, pose)) == 0


def test_a_teleport_or_a_sudden_turn_between_two_messages_is_a_jump():
    t, pose = straight(100, 0.4)
    pose[60:, 0] -= 0.25
    pose[80:, 2] += 0.6
    assert list(pose_jumps(t, pose)) == [60, 80]


def test_motion_across_a_gap_in_the_messages_is_not_a_jump():
    t, pose = straight(100, 0.4)
    keep = np.r_[0:40, 90:100]  # 1 s without messages: 0.4 m travelled at 0.4 m/s
    assert len(pose_jumps(t[keep], pose[keep])) == 0
    pose[90:, 0] += 1.5  # ...but 1.9 m in 1 s is not driving
    assert list(pose_jumps(t[keep], pose[keep])) == [40]


def test_jumps_on_several_streams_at_once_are_one_reset():
    jumps = [
        PoseJump("/robot_1/ground_truth", 10 * NS - TICK_NS, 10 * NS),
        PoseJump("/robot_1/odom", 10 * NS - 2 * TICK_NS, 10 * NS + TICK_NS),  # a lost message on each side
        PoseJump("/robot_2/ground_truth", 10 * NS - TICK_NS, 10 * NS),
    ]
    # between the latest pose before a jump and the earliest after one
    assert reset_boundaries(jumps) == [(10 * NS - TICK_NS, 10 * NS)]


def test_streams_whose_clocks_disagree_leave_out_the_poses_in_between():
    jumps = [
        PoseJump("/robot_1/ground_truth", 10 * NS - TICK_NS, 10 * NS),
        PoseJump("/robot_2/ground_truth", 10 * NS + TICK_NS, 10 * NS + 2 * TICK_NS),  # 30 ms late
    ]
    assert reset_boundaries(jumps) == [(10 * NS - TICK_NS, 10 * NS + 2 * TICK_NS)]


def test_a_jump_of_one_stream_alone_is_not_a_reset():
    glitch = [  # a motion-capture glitch: out and back on the same stream
        PoseJump("/robot_3/ground_truth", 5 * NS, 5 * NS + TICK_NS),
        PoseJump("/robot_3/ground_truth", 5 * NS + TICK_NS, 5 * NS + 2 * TICK_NS),
    ]
    restart = [PoseJump("/robot_2/odom", 7 * NS, 7 * NS + TICK_NS)]  # one robot's odometry restarting
    far_apart = [PoseJump("/robot_1/odom", 9 * NS, 9 * NS + TICK_NS), PoseJump("/robot_2/odom", 11 * NS, 11 * NS)]
    assert reset_boundaries(glitch + restart + far_apart) == []


def fleet_recording(seed: int, resets_s: tuple[float, ...], end_s: float) -> tuple[dict[str, PoseSeries], np.ndarray]:
    """Three robots driving random arcs, put back at their starts (odometry restarted there) at `resets_s`.

    Ground truth at 50 Hz, odometry at 25 Hz, 10 % of messages lost; robot_1 stands still in the
    second episode (no jump of its own at the second reset); robot_2's odometry restarts at the
    origin in the middle of the third episode and robot_3's ground truth glitches once in the first.
    Returns the streams and the episode of each tick.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(round(end_s * NS / TICK_NS)) * TICK_NS
    episode = np.searchsorted(np.asarray(resets_s) * NS, t, side="right")
    truth = np.zeros((3, len(t), 3))
    odom = np.zeros((3, len(t), 3))
    v = rng.uniform(0.1, 0.4, 3)
    w = rng.uniform(-0.3, 0.3, 3)
    pose = STARTS.copy()
    odo = STARTS.copy()
    for k in range(len(t)):
        if k and episode[k] != episode[k - 1]:
            pose, odo = STARTS.copy(), STARTS.copy()
        elif k:
            if k % 50 == 0:
                v, w = rng.uniform(0.1, 0.4, 3), rng.uniform(-0.3, 0.3, 3)
            moving = np.ones(3) if episode[k] != 1 else np.array([0.0, 1.0, 1.0])
            step = v * moving * TICK_NS / NS
            turn = w * moving * TICK_NS / NS
            for p, scale in ((pose, 1.0), (odo, 1.04)):
                p[:, 0] += scale * step * np.cos(p[:, 2])
                p[:, 1] += scale * step * np.sin(p[:, 2])
                p[:, 2] = np.angle(np.exp(1j * (p[:, 2] + turn)))
        truth[:, k] = pose
        odom[:, k] = odo
    restart = np.flatnonzero(t >= (resets_s[1] + end_s) / 2 * NS)[0]
    odom[1, restart:] -= odom[1, restart]
    glitch = np.flatnonzero(t >= resets_s[0] / 2 * NS)[0]
    truth[2, glitch, :2] += 0.5
    streams: dict[str, PoseSeries] = {}
    for i in range(3):
        got = rng.random(len(t)) > 0.1
        streams[f"/robot_{i + 1}/ground_truth"] = series(t[got], truth[i, got])
        got &= np.arange(len(t)) % 2 == 0
        streams[f"/robot_{i + 1}/odom"] = series(t[got], odom[i, got])
    return streams, episode


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_episodes_are_split_at_the_resets_and_nowhere_else(seed):
    resets_s = (8.0, 16.0)
    streams, episode = fleet_recording(seed, resets_s, 24.0)
    t = np.arange(len(episode)) * TICK_NS
    windows = infer_episodes(streams, 0, int(t[-1]))
    assert [w.episode for w in windows] == [0, 1, 2]
    assert windows[0].start_ns == 0 and windows[-1].end_ns == t[-1]
    for w, reset_s in zip(windows, resets_s, strict=False):
        # the episode ends with the last pose before the reset (a few lost messages of slack)
        assert reset_s * NS - 10 * TICK_NS <= w.end_ns < reset_s * NS
    for before, after in pairwise(windows):
        assert after.start_ns > before.end_ns and after.start_ns <= before.end_ns + 10 * TICK_NS
    for topic, s in streams.items():  # every pose inside a window belongs to that window's episode
        for w in windows:
            inside = (s.time.t_ns >= w.start_ns) & (s.time.t_ns <= w.end_ns)
            assert set(episode[s.time.t_ns[inside] // TICK_NS]) == {w.episode}, topic


def test_a_recording_without_resets_is_one_episode():
    streams, _ = fleet_recording(3, (8.0, 16.0), 24.0)
    first = {
        topic: series(s.time.t_ns[s.time.t_ns < 8 * NS], s.pose[s.time.t_ns < 8 * NS]) for topic, s in streams.items()
    }
    (window,) = infer_episodes(first, 0, 8 * NS)
    assert (window.start_ns, window.end_ns, window.seed) == (0, 8 * NS, None)
