"""The deploy runner's parts on their own: staleness rule, odometry rebasing, the reset handshake,
the latest samples of an episode, and the episode tally shared with the simulated loop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from pipeline.core.judge import EpisodeJudge, RewardWeights
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import load_scenario
from pipeline.rollout.errors import DeployAborted, FleetNotReady
from pipeline.rollout.handshake import ResetHandshake
from pipeline.rollout.link import LatestSamples
from pipeline.rollout.tally import EpisodeTally
from pipeline.rollout.watch import OdometryFrame, StalenessWatch, compose, inverse
from pipeline.ros.buffers import JointState, PoseSample, RobotState, ScanSample

MS = 1_000_000


# -- staleness ------------------------------------------------------------------------------------


def test_a_robot_aborts_only_after_staying_stale_for_the_outage_limit():
    watch = StalenessWatch(outage_ns=500 * MS, robots=("robot_1",))
    first = watch.update(0, {"robot_1": "scan 300 ms old"})
    assert first.began == {"robot_1": "scan 300 ms old"} and first.outage == {} and first.ended == {}
    assert watch.update(400 * MS, {"robot_1": "scan 700 ms old"}).outage == {}
    later = watch.update(500 * MS, {"robot_1": "scan 800 ms old"})
    assert later.outage == {"robot_1": "scan 800 ms old"} and later.began == {}


def test_fresh_data_ends_the_interval_counts_its_seconds_and_a_reset_forgets_it():
    watch = StalenessWatch(outage_ns=500 * MS, robots=("robot_1", "robot_2"))
    watch.update(0, {"robot_1": "old", "robot_2": "old"})
    back = watch.update(300 * MS, {"robot_2": "old"})  # robot_1 fresh again
    assert back.ended == {"robot_1": 0.3} and back.began == {}
    again = watch.update(600 * MS, {"robot_1": "old", "robot_2": "old"})
    assert again.outage == {"robot_2": "old"} and again.began == {"robot_1": "old"}
    assert watch.stale_s(700 * MS) == pytest.approx([0.3 + 0.1, 0.7])
    watch.reset()
    assert watch.update(700 * MS, {"robot_2": "old"}).outage == {}
    assert watch.stale_s(700 * MS) == pytest.approx([0.0, 0.0])


# -- odometry frame -------------------------------------------------------------------------------


def test_rebased_odometry_starts_at_the_starts_and_keeps_relative_motion():
    rng = np.random.default_rng(4)
    starts = np.array([[1.0, 1.0, 0.0], [4.0, 2.0, np.pi], [2.5, 3.0, -1.2]])
    odom0 = rng.uniform(-3, 3, size=(3, 3))
    odom0[:, 2] = rng.uniform(-np.pi, np.pi, 3)
    frame = OdometryFrame(3)
    frame.rebase(starts, odom0)
    np.testing.assert_allclose(frame.to_map(odom0), starts, atol=1e-12)
    motion = np.array([[0.3, 0.0, 0.2], [0.1, -0.2, 0.0], [0.0, 0.0, 1.0]])  # in each robot's body frame
    moved = frame.to_map(compose(odom0, motion))
    np.testing.assert_allclose(moved, compose(starts, motion), atol=1e-12)
    np.testing.assert_allclose(compose(odom0, inverse(odom0)), np.zeros((3, 3)), atol=1e-12)


# -- reset handshake ------------------------------------------------------------------------------


def test_the_handshake_publishes_and_returns_when_the_fleet_confirms():
    sent = []
    handshake = ResetHandshake(lambda e, s: sent.append((e, s)), timeout_s=5.0)
    timer = threading.Timer(0.05, handshake.confirmed, args=(3, 42))
    timer.start()
    started = time.monotonic()
    handshake.request(3, 42)
    assert sent == [(3, 42)] and time.monotonic() - started < 4.0


def test_a_confirmation_for_another_episode_does_not_count():
    handshake = ResetHandshake(lambda e, s: handshake.confirmed(e - 1, s), timeout_s=0.3)
    with pytest.raises(FleetNotReady, match=r"did not confirm the reset of episode 5 within 0\.3 s"):
        handshake.request(5, 9)


def test_a_fleet_that_dies_during_the_handshake_is_reported():
    def dead() -> None:
        raise DeployAborted("the twin exited with status -9", [])

    handshake = ResetHandshake(lambda e, s: None, timeout_s=5.0, check_alive=dead)
    with pytest.raises(DeployAborted, match="status -9"):
        handshake.request(0, 0)


def test_an_operator_confirms_instead_of_the_fleet():
    asked, sent = [], []
    handshake = ResetHandshake(lambda e, s: sent.append(e), timeout_s=0.1, operator=asked.append)
    handshake.request(7, 1)
    assert asked == [7] and sent == []


# -- latest samples -------------------------------------------------------------------------------

GEOMETRY = ScanGeometry(4, 0.0, 2 * np.pi / 4, 0.05, 5.0)


def _state(t: int, scan: bool = True, odom: bool = True, truth: bool = True) -> JointState:
    robot = RobotState(
        ScanSample(t, t, np.full(4, 1.0 + t), GEOMETRY) if scan else None,
        PoseSample(t, t, np.array([t, 0.0, 0.0])) if odom else None,
        PoseSample(t, t, np.array([t, 1.0, 0.0])) if truth else None,
        None,
        None,
        None,
    )
    return JointState(t, {"robot_1": robot})


def test_a_missing_sample_holds_the_last_one_of_the_episode():
    samples = LatestSamples(["robot_1"], use_truth=True)
    samples.arrays(_state(1))
    scans, geoms, odom, truth = samples.arrays(_state(2, scan=False))
    assert scans[0][0] == 2.0 and geoms[0] == GEOMETRY  # the scan of time 1
    assert odom[0, 0] == 2 and truth is not None and truth[0, 0] == 2


def test_no_sample_since_the_reset_stops_the_episode_naming_the_topic():
    samples = LatestSamples(["robot_1"], use_truth=True)
    samples.arrays(_state(1))
    samples.clear()
    with pytest.raises(FleetNotReady, match="/robot_1/odom"):
        samples.arrays(_state(2, odom=False))


def test_ground_truth_is_optional_when_the_fleet_has_none():
    samples = LatestSamples(["robot_1"], use_truth=False)
    _, _, odom, truth = samples.arrays(_state(1, truth=False))
    assert truth is None and odom.shape == (1, 3)


# -- tally ----------------------------------------------------------------------------------------


def test_the_tally_counts_arrivals_paths_and_the_outcome():
    scenario = load_scenario("empty")
    judge = EpisodeJudge(scenario, RewardWeights(), max_steps=500, distance="euclidean")
    starts = scenario.starts.copy()
    judge.reset(starts)
    tally = EpisodeTally(0, 11, scenario.robot_names, 0.1)
    tally.start(starts)
    goals = scenario.goals[:, :2]
    poses = starts.copy()
    for _ in range(3):  # robot 0 drives 0.1 m per step straight at its goal, the others stand
        direction = goals[0] - poses[0, :2]
        poses[0, :2] += 0.1 * direction / np.linalg.norm(direction)
        judged = judge.step(poses, poses, np.full((scenario.n_robots, 15), 5.0))
        tally.stepped(poses)
        tally.judged(judged, judge.steps)
    poses[0, :2] = goals[0]
    judged = judge.step(poses, poses, np.full((scenario.n_robots, 15), 5.0))
    tally.stepped(poses)
    tally.judged(judged, judge.steps)
    result = tally.result(judge)
    assert result.seed == 11 and result.steps == 4
    assert result.time_to_goal_s[0] == pytest.approx(0.4) and np.isnan(result.time_to_goal_s[1:]).all()
    assert result.path_length_m[0] == pytest.approx(np.linalg.norm(goals[0] - starts[0, :2]))
    assert (result.path_length_m[1:] == 0).all()
    assert tally.outcome() == "incomplete" and tally.outcome(aborted=True) == "aborted"
    assert result.trajectory.shape == (5, scenario.n_robots, 3)
