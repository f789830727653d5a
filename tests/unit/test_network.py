"""The network between sensors and policy: loss in bursts, delay and jitter, the staleness rule, and one rule for
what a stale robot observes and does, shared by the simulator and the deploy runner (bit for bit)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from pipeline.core.network import BurstLoss, LinkSettings, MessageStream, observed_scans, stand_still
from pipeline.rollout.link import LatestSamples
from pipeline.ros.buffers import PoseSample, ReceiverBuffer, ScanSample
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

MS = 1_000_000


@pytest.mark.parametrize(("loss", "burst"), [(0.04, 4.0), (0.1, 1.0), (0.02, 8.0)])
def test_burst_loss_has_the_stationary_loss_and_the_mean_burst_it_was_given(loss, burst):
    rng = np.random.default_rng(1)
    chain = BurstLoss(loss, burst, 1)
    chain.reset(rng)
    lost = np.array([chain.lost(0, rng) for _ in range(200_000)])
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2]
    assert lost.mean() == pytest.approx(loss, rel=0.1)
    assert runs.mean() == pytest.approx(burst, rel=0.1)


def test_a_stream_delivers_at_its_rate_after_its_delay_and_keeps_what_arrived_last():
    rng = np.random.default_rng(0)
    stream = MessageStream(LinkSettings(rate_hz=10.0, delay_s=0.25), 1, 100 * MS)
    stream.reset(0, [np.array([0.0])], rng)
    seen = []
    for k in range(1, 21):
        stream.step(k * 100 * MS, [np.array([float(k)])], rng)
        seen.append((stream.latest[0][0], stream.ages_ns(k * 100 * MS)[0]))
    # each message is produced at 10 Hz and arrives 250 ms later: the policy sees the reading of 2-3 steps ago
    values = [v for v, _ in seen[5:]]
    assert all(np.diff(values) >= 0) and max(k - v for k, (v, _) in zip(range(6, 21), seen[5:], strict=True)) <= 3
    assert all(age < 100 * MS for _, age in seen[5:])  # a message arrived within every control period
    assert stream.sent[0] == 20 and stream.lost[0] == 0


def test_observed_scans_hold_or_blank_and_stale_robots_stand_still():
    scans = [np.array([1.0, 2.0]), np.array([3.0, 4.0])]
    stale = np.array([False, True])
    held = observed_scans(scans, stale, "hold")
    blank = observed_scans(scans, stale, "blank")
    assert np.array_equal(held[1], scans[1]) and np.array_equal(blank[0], scans[0])
    assert np.isinf(blank[1]).all()
    commands = stand_still(np.ones((2, 2)), stale)
    assert commands.tolist() == [[1.0, 1.0], [0.0, 0.0]]


def lossy_world(stale_scan: str = "hold"):
    scenario, world = make_world()
    network = replace(
        world.network,
        scan_rate_hz=7.0,
        odom_rate_hz=20.0,
        loss_prob=0.08,
        burst_len=6.0,
        delay_s=0.03,
        jitter_s=0.02,
        stale_scan=stale_scan,
    )
    return scenario, replace(world, network=network)


def rollout(sim: MultiRobotSim, seed: int, steps: int = 120):
    sim.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        result = sim.step(rng.uniform(-1, 1, size=(sim.n, 2)))
        out.append((result.obs.copy(), sim.stale.copy(), sim.last_cmd.copy()))
    return out


def test_a_lossy_network_in_the_simulator_is_deterministic_and_stale_robots_stand_still():
    scenario, world = lossy_world()
    a, b = rollout(MultiRobotSim(scenario, world), 3), rollout(MultiRobotSim(scenario, world), 3)
    assert all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) for x, y in zip(a, b, strict=True))
    stale = np.array([s for _, s, _ in a])
    assert 0.01 < stale.mean() < 0.5  # bursts of lost scans make robots stale now and then
    # a robot stale at a step gets no command in the next one
    for (_, was_stale, _), (_, _, cmd) in itertools.pairwise(a):
        assert np.all(cmd[was_stale] == 0.0)


def test_an_ideal_link_leaves_the_simulator_as_it_was():
    scenario, world = make_world()
    assert not world.network.plays
    sim = MultiRobotSim(scenario, world)
    plain = rollout(sim, 5)
    assert not np.array([s for _, s, _ in plain]).any()
    # the same rollout with a network section that plays nothing at all
    same = rollout(MultiRobotSim(scenario, replace(world, network=replace(world.network, stale_scan="blank"))), 5)
    assert all(np.array_equal(x[0], y[0]) for x, y in zip(plain, same, strict=True))


@pytest.mark.parametrize("stale_scan", ["hold", "blank"])
def test_the_simulator_and_the_deploy_runner_observe_the_same_from_the_same_deliveries(stale_scan):
    """The sim's network deliveries are fed to the deploy side's receiver buffer at their receive times: the
    staleness it reports, and the observation built by the runner's parts, equal the simulator's to the bit."""
    scenario, world = lossy_world(stale_scan)
    sim = MultiRobotSim(scenario, world)
    names = list(scenario.robot_names)
    net = world.network
    receiver = ReceiverBuffer(
        names, capacity=64, scan_stale_ns=round(net.scan_stale_s * 1e9), odom_stale_ns=round(net.odom_stale_s * 1e9)
    )
    samples = LatestSamples(names, use_truth=False)
    builder = sim.mdp.observer  # the same MDP parts as a runner builds for this policy's world
    sim.reset(seed=11)
    rng = np.random.default_rng(11)
    last_seen = {ns: (-2, -2) for ns in names}
    checked = stale_seen = 0
    for step in range(200):
        streams = sim.network
        assert streams.scans is not None and streams.odometry is not None
        t = streams.t_ns
        for i, ns in enumerate(names):  # what arrived since the last step, at its receive time
            scan_t, odom_t = int(streams.scans.receive_ns[i]), int(streams.odometry.receive_ns[i])
            if scan_t != last_seen[ns][0]:
                receiver.add_scan(ns, ScanSample(scan_t, scan_t, streams.scans.latest[i], sim.world.scan_geometry))
            if odom_t != last_seen[ns][1]:
                receiver.add_odom(ns, PoseSample(odom_t, odom_t, streams.odometry.latest[i]))
            last_seen[ns] = (scan_t, odom_t)
        state = receiver.joint_state(t)
        stale = np.array([ns in state.stale for ns in names])
        assert np.array_equal(stale, sim.stale), step
        scans, geoms, odom, _ = samples.arrays(state)
        seen = builder.build(observed_scans(scans, stale, stale_scan), geoms, odom)
        assert np.array_equal(seen.obs, sim.obs), step
        checked += 1
        stale_seen += int(stale.any())
        result = sim.step(rng.uniform(-1, 1, size=(sim.n, 2)))
        if result.judge.done.all() or result.judge.truncated:
            break
    assert checked > 50 and stale_seen > 0


def test_the_robots_clock_stamps_the_simulated_sensor_messages():
    from pipeline.rollout.sim import robot_stamp

    _, world = make_world()
    assert robot_stamp(5 * 10**9, world) == 5 * 10**9  # the ideal clock: the controller's
    skewed = replace(world, network=replace(world.network, clock_offset_s=0.035, clock_drift_ppm=40.0))
    assert robot_stamp(10 * 10**9, skewed) == 10 * 10**9 + 35_000_000 + 400_000
    early = replace(world, network=replace(world.network, clock_offset_s=-2.0))
    assert robot_stamp(10**9, early) == 0
