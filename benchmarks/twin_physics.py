"""Speed of the twin's wheel-level physics: ``python benchmarks/twin_physics.py [--seconds S]``.

For the bundled 3-robot (obstacles) and 6-robot (six) rooms it steps the MuJoCo wheel model with all
wheels driven for S simulated seconds at the twin's 2 ms step and casts a lidar's worth of rays per
robot per step (360 beams at 8 Hz, spread over the sweep as with motion distortion), and prints
physics steps per second, rays per second and the real-time factor (simulated seconds per wall
second; the twin runs at time scales up to 5, so the limit is 5).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pipeline.core.scenario import load_scenario
from pipeline.twin.physics import BaseParams, FleetPhysics
from pipeline.twin.profile import load_profile

ROOT = Path(__file__).resolve().parents[1]

LIMIT = 5.0


def measure(scenario_name: str, seconds: float) -> None:
    scenario = load_scenario(scenario_name)
    base = load_profile("lab")[1].base
    physics = FleetPhysics(scenario, BaseParams(**base.__dict__))
    n = scenario.n_robots
    steps = round(seconds / physics.timestep_s)
    beams_per_step = 360 * 8 * physics.timestep_s  # 5.76: 5 or 6 beams per step
    rng = np.random.default_rng(0)
    targets = rng.uniform(2.0, 8.0, size=(n, 2))
    rays = 0
    started = time.perf_counter()
    for k in range(steps):
        if k % 500 == 0:
            targets = rng.uniform(-4.0, 8.0, size=(n, 2))
            physics.set_wheel_targets(targets)
        physics.step(1)
        count = int((k + 1) * beams_per_step) - int(k * beams_per_step)
        poses = physics.poses()
        for i in range(n):
            physics.cast(i, poses[i, :2], poses[i, 2] + rng.uniform(0, 2 * np.pi, count))
            rays += count
    wall = time.perf_counter() - started
    factor = seconds / wall
    print(
        f"{scenario_name}: robots={n} steps_per_s={steps / wall:.0f} rays_per_s={rays / wall:.0f} "
        f"real_time_factor={factor:.1f} ratio_to_limit={factor / LIMIT:.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    for name in ("obstacles", "six"):
        measure(name, args.seconds)


if __name__ == "__main__":
    main()
