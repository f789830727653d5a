"""Log analysis speed against raw MCAP reading: ``python benchmarks/log_io.py [--hours H] [--robots N]``.

Generates (once, cached in the temp folder under a name keyed by the parameters) a recording
equivalent to a deployment of `robots` robots for `hours` hours at the contract rates: scan 10 Hz
with 360 beams, odometry, ground truth and cmd_vel 50 Hz, observation and action 10 Hz, plus
episode events (60 s episodes with a 2 s reset between them). Messages are pre-serialized
templates whose header stamps are patched, written with ``write_cdr``.

Then, in the same run, it measures (a) the raw read rate, every message of the file through
``McapLog.raw`` (messages/s: the limit, as nothing is decoded) and (b) the analysis rate, the
messages that end up in polars frames per second of building the episodes table, both pose frames
and the scan frames of every robot from a fresh :class:`~pipeline.analysis.tables.Recording`
whose topics are read in one pass (``Recording.load``); the same frames built on demand, one pass
over the file per call, are timed too.
Last line: ``ratio=<analysis/raw> seconds_per_hour=<analysis seconds per recorded hour>``; the
target is at most 10 s per hour.
"""

from __future__ import annotations

import argparse
import math
import os
import struct
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.analysis.tables import EPISODE_TOPIC, Recording
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import load_scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.mappings import to_mapping
from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.record import McapLog
from pipeline.record.session import SessionLog, dumps, session_metadata

ROOT = Path(__file__).resolve().parents[1]

TICK_NS = 20_000_000  # 50 Hz
SLOW_EVERY = 5  # 10 Hz = every 5th tick
EPISODE_S = 60
RESET_S = 2
BEAMS = 360
POOL = 200
FORMAT_VERSION = 2  # 2: start events carry the seed in its own field
_STAMP = struct.Struct("<iI")


def recording_path(hours: float, robots: int) -> Path:
    """The cached recording for these parameters."""
    name = f"mrl_log_io_v{FORMAT_VERSION}_{hours:g}h_{robots}r_{BEAMS}b.mcap"
    return Path(tempfile.gettempdir()) / name


def _stamped(template: bytes, t_ns: int) -> bytes:
    buf = bytearray(template)
    _STAMP.pack_into(buf, 4, t_ns // NS_PER_S, t_ns % NS_PER_S)
    return bytes(buf)


def generate(path: Path, hours: float, n_robots: int) -> int:
    """Write the benchmark recording to `path`; returns its message count."""
    store = message_store()
    scenario = load_scenario("obstacles")
    robots = [f"robot_{i + 1}" for i in range(n_robots)]
    rng = np.random.default_rng(0)
    geometry = ScanGeometry(BEAMS, -math.pi, 2 * math.pi / BEAMS, 0.12, 12.0)
    angle = np.linspace(0, 2 * math.pi, POOL, endpoint=False)
    pools: dict[str, list[bytes]] = {}
    for i, ns in enumerate(robots):
        cx, cy = 1.5 + 1.5 * i, 2.0
        poses = np.stack([cx + 0.8 * np.cos(angle), cy + 0.8 * np.sin(angle), angle + math.pi / 2], axis=1)
        pools[f"/{ns}/odom"] = [
            store.serialize(C.odometry(0, ns, p, (0.3, 0.1), store=store), T.ODOMETRY) for p in poses
        ]
        pools[f"/{ns}/ground_truth"] = [
            store.serialize(C.pose_stamped(0, "map", p, store=store), T.POSE_STAMPED) for p in poses
        ]
        pools[f"/{ns}/cmd_vel"] = [
            store.serialize(C.twist(0.3, 0.1 * math.sin(a), store=store), T.TWIST) for a in angle
        ]
        ranges = rng.uniform(0.2, 6.0, size=(POOL, BEAMS)).astype(np.float32)
        pools[f"/{ns}/scan"] = [
            store.serialize(C.laser_scan(0, f"{ns}/laser", r, geometry, store=store), T.LASER_SCAN) for r in ranges
        ]
        obs = rng.normal(size=(POOL, 19)).astype(np.float32)
        pools[f"obs/{ns}"] = [
            store.serialize(C.observation(0, 0, 0, ns, "rich", o, store=store), T.OBSERVATION) for o in obs
        ]
        pools[f"act/{ns}"] = [
            store.serialize(C.action(0, 0, 0, ns, o[:2], (0.3, 0.1), store=store), T.ACTION) for o in obs
        ]
    session = session_metadata("real", scenario.name, robots, 0.1, profile="benchmark")
    documents = {"scenario": dumps(to_mapping(scenario))}
    ticks = int(hours * 3600 * NS_PER_S // TICK_NS)
    episode_ticks = EPISODE_S * NS_PER_S // TICK_NS
    cycle_ticks = (EPISODE_S + RESET_S) * NS_PER_S // TICK_NS
    t0 = 1_700_000_000 * NS_PER_S
    partial = path.with_suffix(".partial")
    count = 0
    with SessionLog(partial, robots, session, documents) as log:
        write = log.raw
        for k in range(ticks):
            t = t0 + k * TICK_NS
            phase, episode = k % cycle_ticks, k // cycle_ticks
            j = k % POOL
            if phase == 0:
                log.start_episode(t, episode, episode)
                count += 1
            for ns in robots:
                write(f"/{ns}/odom", _stamped(pools[f"/{ns}/odom"][j], t), t, t)
                write(f"/{ns}/ground_truth", _stamped(pools[f"/{ns}/ground_truth"][j], t), t, t)
                write(f"/{ns}/cmd_vel", pools[f"/{ns}/cmd_vel"][j], t)
                count += 3
                if k % SLOW_EVERY == 0:
                    write(f"/{ns}/scan", _stamped(pools[f"/{ns}/scan"][j // SLOW_EVERY], t), t, t)
                    write("/mrl/observation", _stamped(pools[f"obs/{ns}"][j], t), t)
                    write("/mrl/action", _stamped(pools[f"act/{ns}"][j], t), t)
                    count += 3
            if phase == episode_ticks // 2:
                for i, ns in enumerate(robots):
                    log.event(t, episode, phase // SLOW_EVERY, "goal" if (episode + i) % 4 else "collision", ns)
                    count += 1
            if phase == episode_ticks:
                log.event(t, episode, episode_ticks // SLOW_EVERY, "end", detail="incomplete")
                count += 1
    os.replace(partial, path)
    return count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--regenerate", action="store_true", help="write the recording even if it is cached")
    args = parser.parse_args()
    path = recording_path(args.hours, args.robots)
    if args.regenerate or not path.exists():
        start = time.perf_counter()
        generate(path, args.hours, args.robots)
        print(f"generated {path} in {time.perf_counter() - start:.1f} s")
    else:
        print(f"cached recording {path}")

    start = time.perf_counter()
    total = sum(1 for _ in McapLog(path).raw())
    raw_s = time.perf_counter() - start
    raw_rate = total / raw_s

    start = time.perf_counter()
    recording = Recording(path)
    recording.load([EPISODE_TOPIC, *recording.robot_topics("ground_truth", "odom", "scan")])  # one pass
    episodes = recording.episodes_table()
    truth = recording.poses("ground_truth")
    odom = recording.poses("odom")
    scans = [recording.topic_frame(f"/{r}/scan") for r in recording.robots]
    analysis_s = time.perf_counter() - start
    events = recording.events().height
    analysed = truth.height + odom.height + sum(s.height for s in scans) + events
    analysis_rate = analysed / analysis_s
    seconds_per_hour = analysis_s / args.hours

    start = time.perf_counter()
    on_demand = Recording(path)
    on_demand.episodes_table()
    on_demand.poses("ground_truth")
    on_demand.poses("odom")
    for r in on_demand.robots:
        on_demand.topic_frame(f"/{r}/scan")
    on_demand_s = time.perf_counter() - start

    size_mb = path.stat().st_size / 1e6
    print(f"recording: {total} messages, {size_mb:.0f} MB, {args.hours:g} h, {args.robots} robots")
    print(f"raw: {raw_rate:,.0f} messages/s ({raw_s:.2f} s for every message of the file)")
    print(
        f"analysis: {analysis_rate:,.0f} messages/s into polars ({analysed} messages: {episodes.height} episode rows, "
        f"{truth.height} + {odom.height} poses, {sum(s.height for s in scans)} scans, {events} events) "
        f"in {analysis_s:.2f} s"
    )
    print(f"on demand (one pass per call instead of one pass for all): {on_demand_s:.2f} s")
    print(f"analysis/raw = {analysis_rate / raw_rate:.3f}; {seconds_per_hour:.2f} s per recorded hour (target <= 10 s)")
    print(f"ratio={analysis_rate / raw_rate:.3f} seconds_per_hour={seconds_per_hour:.2f}")


if __name__ == "__main__":
    main()
