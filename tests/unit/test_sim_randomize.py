"""The simulator's new parameters (range-dependent noise, mounting offset, wheel deadband, arc per metre) and
per-episode domain randomization, in real MuJoCo."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.scenario import load_scenario
from pipeline.errors import ConfigError
from pipeline.params import world_config
from pipeline.sim.env import MultiRobotSim
from pipeline.sim.world import SimWorld

SCENARIO = load_scenario("obstacles")
QUIET = {"lidar": {"noise_sigma_m": 0.0, "dropout_prob": 0.0}, "odometry": {"drift_per_m": 0.0}}


def drive(world_overrides: dict, cmd: tuple[float, float], steps: int = 20, seed: int = 0) -> SimWorld:
    world = SimWorld(SCENARIO, world_config({**QUIET, **world_overrides}))
    world.reset(seed)
    for _ in range(steps):
        world.step(np.tile(np.array(cmd), (SCENARIO.n_robots, 1)))
    return world


def test_a_deadband_stops_slow_turns_and_unequal_wheels_make_an_arc():
    start = SCENARIO.starts[:, 2]

    def turn(w: SimWorld) -> np.ndarray:
        return np.angle(np.exp(1j * (w.truth[:, 2] - start)))

    turned = turn(drive({}, (0.0, 0.15)))
    assert np.all(np.abs(turned) > 0.2)  # 0.15 rad/s for 2 s
    # 0.15 rad/s on a 0.281 m axle is 0.62 rad/s at 0.034 m wheels: under a 1 rad/s deadband nothing turns
    held = turn(drive({"actuation": {"deadband_radps": 1.0}}, (0.0, 0.15)))
    assert np.all(np.abs(held) < 1e-3)
    straight = drive({}, (0.2, 0.0), steps=10)
    arc = drive({"actuation": {"yaw_rate_per_mps": 0.5}}, (0.2, 0.0), steps=10)
    assert np.all(np.abs(turn(straight)) < 1e-3)
    # 0.2 m/s for 1 s at 0.5 rad/s per m/s: about 0.1 rad, less the servo's lag
    assert np.all((turn(arc) > 0.07) & (turn(arc) < 0.11))


def test_the_beams_start_at_the_mounting_offset():
    centred = drive({}, (0.0, 0.0), steps=1).true_ranges()
    ahead = drive({"lidar": {"mount_xy_m": [0.05, 0.0]}}, (0.0, 0.0), steps=1).true_ranges()
    n = centred.shape[1]
    # beam 0 looks forward, beam n/2 backward
    assert np.allclose(ahead[:, 0], centred[:, 0] - 0.05, atol=0.01)
    assert np.allclose(ahead[:, n // 2], centred[:, n // 2] + 0.05, atol=0.01)


def test_noise_grows_with_range():
    world = SimWorld(SCENARIO, world_config({"lidar": {"noise_sigma_m": 0.002, "noise_per_m": 0.01}}))
    world.reset(3)
    true = world.true_ranges()
    # beams with no return read inf in both; they are left out below (inf - 0 keeps them out of the arithmetic)
    errors = np.stack([world.scan() - np.where(np.isfinite(true), true, 0.0) for _ in range(200)])
    near, far = true < 1.5, (true > 3.0) & np.isfinite(true)
    for sel in (near, far):
        expected = np.sqrt(np.mean((0.002 + 0.01 * true[sel]) ** 2))
        assert float(np.sqrt(np.mean(errors[:, sel] ** 2))) == pytest.approx(expected, rel=0.05)
    assert np.sqrt(np.mean(errors[:, far] ** 2)) > 2 * np.sqrt(np.mean(errors[:, near] ** 2))


RANDOM = {
    "randomize": {
        "actuation": {"delay_s": [0.0, 0.2], "linear_gain": [0.6, 1.0]},
        "lidar": {"bias_m": [-0.05, 0.05]},
    }
}


def test_each_episode_draws_its_world_from_its_seed():
    sim = MultiRobotSim(SCENARIO, world_config({**QUIET, **RANDOM}))
    runs = {}
    for seed in (1, 2, 1):
        sim.reset(seed)
        for _ in range(15):
            sim.step(np.full((SCENARIO.n_robots, 2), 0.8, dtype=np.float32))
        draws = sim.world.draws
        assert list(draws) == ["lidar.bias_m", "actuation.delay_s", "actuation.linear_gain"]
        assert 0.0 <= draws["actuation.delay_s"] <= 0.2 and 0.6 <= draws["actuation.linear_gain"] <= 1.0
        assert sim.world.world.actuation.delay_s == draws["actuation.delay_s"]
        runs.setdefault(seed, []).append((dict(draws), sim.world.truth.copy(), sim.obs.copy()))
    # the same seed gives the same draws and the same rollout, bit for bit; another seed other ones
    (d1, t1, o1), (d1b, t1b, o1b) = runs[1]
    assert d1 == d1b and np.array_equal(t1, t1b) and np.array_equal(o1, o1b)
    ((d2, t2, _),) = runs[2]
    assert d2 != d1 and not np.allclose(t1, t2)


def test_without_ranges_nothing_is_drawn():
    sim = MultiRobotSim(SCENARIO, world_config(QUIET))
    sim.reset(4)
    assert sim.world.draws == {}


@pytest.mark.parametrize(
    ("ranges", "message"),
    [
        (
            {"actuation": {"delay_s": [0.2, 0.1]}},
            "randomize.actuation.delay_s = [0.2, 0.1]: [low, high] with low <= high",
        ),
        ({"actuation": {"time_constant_s": [0.0, 0.1]}}, "randomize.actuation.time_constant_s = [0.0, 0.1]"),
        ({"lidar": {"bias_m": [0.1]}}, "randomize.lidar.bias_m = [0.1]: [low, high] or [] (off)"),
        ({"lidar": {"range_max_m": [1, 2]}}, "randomize.lidar.range_max_m"),
    ],
)
def test_bad_ranges_are_named(ranges, message):
    with pytest.raises(ConfigError) as err:
        world_config({"randomize": ranges}, source="params.yaml")
    assert message in str(err.value) and "params.yaml" in str(err.value)
