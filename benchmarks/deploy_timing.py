"""Deploy-side timing at 1x time: emitter tick jitter, cross-robot send skew, joint-state age.

For 3 and for 10 robots it trains and exports a tiny shared policy, starts the hardware twin
(mild profile) in its own process, deploys over DDS on loopback for `--seconds`, and computes
from the recorded /mrl/timing:

- tick period p50 and tick jitter p99 (|period - 20 ms|), against the jitter of a bare timer
  loop on the same clock measured in the same run (the limit this machine allows);
- cross-robot send skew p99: within a tick, last send minus first send;
- joint-state age p99: at each control step, control time minus the receive time of each
  robot's latest odometry and scan.

Targets: tick jitter p99 <= 1 ms, skew p99 <= 0.5 ms. Last line:
``ratio=<tick jitter p99 / bare timer jitter p99> jitter_p99_ms=<..> skew_p99_ms=<..>`` (3 robots).

``--link veth``: the twin runs on another host (:mod:`pipeline.bench.hosts`: a network namespace joined by a veth
pair; root only), found through the fleet's peers, the runner here bound to its end of the pair
(``network.interface``); the same figures, over the link. ``--out FILE.json`` writes them with the command and
commit.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml
from collect_results import ROOT, commit_of  # this folder: the script's own

from pipeline.analysis.timing import TimingFigures, timing_figures
from pipeline.bench.hosts import RemoteProcess, dds_environment, other_host
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.clock import WallClock
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world

TICK_NS = 20_000_000
FIELDS = ("tick_p50_ms", "tick_jitter_p99_ms", "skew_p99_ms", "age_p99_ms", "ticks", "stale")


def scenario_file(folder: Path, n: int) -> Path:
    """A room for n robots in two facing rows (robot i crosses to the other side)."""
    cols = (n + 1) // 2
    width = max(6.0, 1.0 * cols + 1.0)
    robots = []
    for i in range(n):
        row, col = divmod(i, cols)
        x = 1.0 + col * (width - 2.0) / max(cols - 1, 1)
        y, gy, yaw = (1.0, 3.0, 1.5707963) if row == 0 else (3.0, 1.0, -1.5707963)
        robots.append({"start": {"x_m": x, "y_m": y, "yaw_rad": yaw}, "goal": {"x_m": x, "y_m": gy}})
    scenario = {
        "name": f"rows{n}",
        "room": {
            "x_min_m": 0.0,
            "x_max_m": width,
            "y_min_m": 0.0,
            "y_max_m": 4.0,
            "wall_thickness_m": 0.1,
            "wall_height_m": 0.5,
        },
        "robot": {
            "radius_m": 0.165,
            "height_m": 0.2,
            "mass_kg": 5.0,
            "wheel_separation_m": 0.281,
            "wheel_diameter_m": 0.068,
        },
        "goal_size_m": 0.4,
        "robots": robots,
        "obstacles": [],
    }
    path = folder / f"rows{n}.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


def tiny_policy(folder: Path, scenario: Path, max_steps: int) -> Path:
    sc, world = make_world(
        world=world_config({"scenario": str(scenario), "observation": "rich", "max_steps": max_steps})
    )
    tiny = {
        "mode": "shared",
        "total_steps": 100,
        "n_envs": 1,
        "net_arch": [16, 16],
        "batch_size": 16,
        "learning_starts": 20,
    }
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), tiny), "<benchmark>")
    result = train(sc, world, cfg, folder / "run", progress=False)
    export_policy(result.checkpoint, folder / "policy", golden_observations(sc, world, 4))
    return folder / "policy"


def fleet_file(
    folder: Path, scenario: Path, n: int, domain: int, network: dict[str, object] | None = None, name: str = ""
) -> Path:
    fleet = {
        "target": "robots" if network and "interface" in network else "twin",
        "transport": "dds",
        "scenario": str(scenario),
        "network": {"domain_id": domain, "loopback_only": True, "peers": [], **(network or {})},
        "robots": [
            {"name": f"robot_{i + 1}", "namespace": f"robot_{i + 1}", "v_max_mps": 0.4, "w_max_radps": 0.2}
            for i in range(n)
        ],
        "twin": {"profile": "mild", "time_scale": 1.0, "seed": 0},
        "timing": {
            "tick_period_s": 0.02,
            "command_validity_s": 0.12,
            "discovery_timeout_s": 30.0,
            "reset_timeout_s": 20.0,
            "scan_stale_s": 0.5,
            "odom_stale_s": 0.3,
            "truth_stale_s": 0.3,
            "outage_limit_s": 5.0,
            "use_ground_truth": True,
        },
    }
    path = folder / f"{name or 'fleet'}{n}.yaml"
    path.write_text(yaml.safe_dump(fleet, sort_keys=False))
    return path


def bare_timer_jitter_ms(seconds: float) -> float:
    """p99 |period - 20 ms| of a loop that only sleeps to a 20 ms grid on the same clock."""
    clock = WallClock()
    stamps = []
    next_t = clock.now_ns()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        clock.sleep_until(next_t)
        stamps.append(clock.now_ns())
        next_t += TICK_NS
    periods = np.diff(stamps) / 1e6
    return float(np.percentile(np.abs(periods - 20.0), 99))


def measure(n: int, seconds: float, folder: Path, domain: int, link: str = "loopback") -> TimingFigures:
    scenario = scenario_file(folder, n)
    max_steps = 100
    policy = tiny_policy(folder / f"p{n}", scenario, max_steps)
    episodes = max(1, round(seconds / (max_steps * 0.1)))
    request = DeployRequest(episodes=episodes, seed=0, recording=folder / f"timing{n}.mcap", progress=False)
    if link == "loopback":
        fleet_path = fleet_file(folder, scenario, n, domain)
        deploy_policy(PolicyRuntime(policy), load_fleet(fleet_path), str(fleet_path), request)
        return timing_figures(folder / f"timing{n}.mcap")
    with other_host(tag=str(n)) as host:  # the twin over there, the runner here on its end of the pair
        there = fleet_file(folder, scenario, n, domain, {"loopback_only": False, "peers": [host.here_addr]}, "twin")
        here = fleet_file(
            folder,
            scenario,
            n,
            domain,
            {"loopback_only": False, "peers": [host.there_addr], "interface": host.here_addr},
        )
        command = [sys.executable, "-m", "pipeline.twin", "--fleet", str(there), "--time-scale", "1"]
        twin = RemoteProcess(host, [*command, "--exit-with-parent"], dds_environment(), ready="twin: ready")
        try:
            twin.wait_ready(60.0)
            deploy_policy(PolicyRuntime(policy), load_fleet(here), str(here), request)
        finally:
            twin.stop()
    return timing_figures(folder / f"timing{n}.mcap")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="deployment time per fleet size")
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 10])
    parser.add_argument("--link", choices=("loopback", "veth"), default="loopback")
    parser.add_argument("--out", type=Path, default=None, help="write the figures to this JSON file")
    args = parser.parse_args()
    rows: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bare = bare_timer_jitter_ms(min(args.seconds, 10.0))
        print(f"bare 20 ms timer loop: jitter p99 {bare:.3f} ms (the limit on this machine)")
        first: TimingFigures | None = None
        for k, n in enumerate(args.robots):
            fig = measure(n, args.seconds, folder, 150 + k, args.link)
            first = first or fig
            rows.append({"robots": n, "link": args.link, **{f: getattr(fig, f) for f in FIELDS}})
            print(
                f"{n:2d} robots: tick p50 {fig.tick_p50_ms:.3f} ms, jitter p99 {fig.tick_jitter_p99_ms:.3f} ms, "
                f"send skew p99 {fig.skew_p99_ms:.3f} ms, joint-state age p99 {fig.age_p99_ms:.1f} ms "
                f"({fig.ticks} ticks, {fig.stale} stale records)"
            )
    assert first is not None
    ratio = first.tick_jitter_p99_ms / max(bare, 1e-6)
    if args.out is not None:
        run = {
            "command": "python " + " ".join(["benchmarks/deploy_timing.py", *sys.argv[1:]]),
            "commit": commit_of(ROOT),
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({**run, "bare_timer_jitter_p99_ms": bare, "rows": rows}, indent=1) + "\n")
    print(f"ratio={ratio:.2f} jitter_p99_ms={first.tick_jitter_p99_ms:.3f} skew_p99_ms={first.skew_p99_ms:.3f}")


if __name__ == "__main__":
    threading.current_thread().name = "benchmark"
    main()
