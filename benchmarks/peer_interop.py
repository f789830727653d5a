"""Interoperability with peers we did not write: the deploy runner and three robot drivers, in C++ or as ROS 2 nodes.

--peer fastdds: the runner on Cyclone DDS and drivers on Debian's Fast DDS (``tests/peers/fastdds_robot``,
from the pipeline's IDL with fastddsgen), over DDS discovery on loopback. --peer roscpp: the runner on
rospy and drivers on Debian's roscpp (``tests/peers/roscpp_robot``), through a private rosmaster on a
free loopback port. --peer rclpy: drivers written as ordinary ROS 2 nodes in rclpy (``tests/peers/rclpy_robot``,
Fast DDS from the ros2 extra's wheels, domain and loopback discovery from the environment as for any ROS 2 node),
the runner on Cyclone DDS or, with ``--transport rclpy``, on rclpy itself. The benchmark builds the driver (the C++
peers), trains and exports a tiny shared policy for the obstacles room, and deploys it for `--episodes` episodes on
three drivers (1x, target ``robots``, the benchmark playing the operator who puts the robots back).

Printed: the jitter of a bare 20 ms timer loop on this machine (the limit the emitter can reach), the
runner's emitter tick jitter p99 and cross-robot send skew p99 from the recorded /mrl/timing (targets
1 ms and 0.5 ms); episodes completed (and aborted); per robot and over all, commands sent during episodes,
commands the driver never received (lost), one-way delay p50/p99 (driver receive time minus the
recorded send time, one host clock); command round trip p50/p99: from sending a new command value
to receiving the first odometry whose twist reports it (the driver applies the command and
publishes it back at 50 Hz); scans recorded vs published.
Last line: ``peer=<peer> transport=<the runner's> episodes=<done>/<asked> lost=<n> jitter_p99_ms=<..>
jitter_ratio=<jitter p99 / bare timer p99> skew_p99_ms=<..> delay_p50_ms=<..> delay_p99_ms=<..> rtt_p50_ms=<..>
rtt_p99_ms=<..>``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the test peers (tests/peers) this drives are not an installed package
from deploy_timing import bare_timer_jitter_ms, tiny_policy  # noqa: E402

from pipeline.analysis.timing import timing_figures  # noqa: E402
from pipeline.record import McapLog  # noqa: E402
from tests.peers import drivers, fastdds, ros1, roscpp  # noqa: E402
from tests.peers import rclpy as rclpy_peer  # noqa: E402

DOMAINS = {"fastdds": 173, "rclpy": 174}
"""The DDS domain of each DDS peer's run (its own: two benchmarks at once never share one)."""
TRANSPORTS = {"fastdds": "dds", "roscpp": "ros1", "rclpy": "dds"}
"""The runner's transport for each peer (rclpy: the default of --transport)."""


def round_trips_s(sent: list[tuple[int, float, float]], odom: list[tuple[int, float, float]]) -> list[float]:
    """For each change of the sent command, the time until an odometry message reports the new value."""
    out = []
    j = 0
    previous = None
    for t, v, w in sent:
        if (v, w) == previous:
            continue
        previous = (v, w)
        while j < len(odom) and odom[j][0] < t:
            j += 1
        k = j
        while k < len(odom) and (odom[k][1], odom[k][2]) != (v, w):
            k += 1
        if k < len(odom) and odom[k][0] - t < 1e9:
            out.append((odom[k][0] - t) / 1e9)
    return out


@contextmanager
def deployer(peer: str, folder: Path, transport: str) -> Iterator[Any]:
    """``deploy(policy, folder, episodes)`` on three drivers of `peer` (with its master, for roscpp), the runner on
    `transport` (rclpy peer only)."""
    if peer == "fastdds":
        binary = fastdds.build()
        yield lambda policy, out, episodes: fastdds.deploy_on_drivers(
            binary, policy, out, episodes, domain=DOMAINS[peer]
        )
        return
    if peer == "rclpy":
        yield lambda policy, out, episodes: rclpy_peer.deploy_on_drivers(
            policy, out, episodes, domain=DOMAINS[peer], transport=transport
        )
        return
    binary = roscpp.build()
    with ros1.master(folder / "ros_home") as uri:
        yield lambda policy, out, episodes: roscpp.deploy_on_drivers(binary, uri, policy, out, episodes)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peer", choices=("fastdds", "roscpp", "rclpy"), default="fastdds")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument(
        "--transport",
        choices=("dds", "rclpy"),
        default=None,
        help="the runner's transport with --peer rclpy: dds (Cyclone DDS, the default) or rclpy",
    )
    args = parser.parse_args()
    if args.transport is not None and args.peer != "rclpy":
        parser.error(f"--transport is for --peer rclpy; the {args.peer} peer's runner is on {TRANSPORTS[args.peer]}")
    transport = args.transport or TRANSPORTS[args.peer]
    reason = {"fastdds": fastdds.missing, "roscpp": roscpp.missing, "rclpy": rclpy_peer.missing}[args.peer]()
    if reason:
        print(f"peer_interop: skipped: {reason}")
        return 1
    bare = bare_timer_jitter_ms(10.0)
    print(f"bare 20 ms timer loop: jitter p99 {bare:.3f} ms (the limit on this machine)")
    with tempfile.TemporaryDirectory() as tmp, deployer(args.peer, Path(tmp), transport) as deploy:
        folder = Path(tmp)
        policy = tiny_policy(folder / "p", Path("obstacles"), 100)
        recording, logs, results = deploy(policy, folder, args.episodes)
        timing = timing_figures(recording)
        log = McapLog(recording)
        episode_times = [m.log_time_ns for m in log.messages(["/mrl/episode"])]
        first, last = min(episode_times), max(episode_times)
        delays: list[float] = []
        rtts: list[float] = []
        lost = sent_total = 0
        for ns in drivers.NAMESPACES:
            driver = drivers.read_log(logs[ns])
            sent = [(m.log_time_ns, m.msg.linear.x, m.msg.angular.z) for m in log.messages([f"/{ns}/cmd_vel"])]
            got = drivers.delivery(sent, driver)
            during = [i for i, s in enumerate(sent) if first <= s[0] <= last]
            missing = sum(1 for i in during if i < got.first_matched)
            if not got.matched:
                print(f"{ns}: the received commands differ from the sent ones")
                missing = len(during)
            odom = [
                (m.log_time_ns, m.msg.twist.twist.linear.x, m.msg.twist.twist.angular.z)
                for m in log.messages([f"/{ns}/odom"])
            ]
            d = np.array(got.delays_s()) * 1e3
            r = np.array(round_trips_s([s for s in sent if first <= s[0] <= last], odom)) * 1e3
            published = sum(1 for k in driver.scans if first <= k[0] * 10**9 + k[1] <= last)
            recorded = sum(1 for m in log.messages([f"/{ns}/scan"]) if first <= m.log_time_ns <= last)
            print(
                f"{ns}: {len(during)} commands during episodes, {missing} lost; delay p50 {np.median(d):.2f} ms "
                f"p99 {np.percentile(d, 99):.2f} ms; round trip p50 {np.median(r):.1f} ms p99 "
                f"{np.percentile(r, 99):.1f} ms ({len(r)} changes); scans recorded {recorded} of {published} published"
            )
            delays += list(d)
            rtts += list(r)
            lost += missing
            sent_total += len(during)
    done = sum(1 for r in results if not r.aborted)
    print(f"episodes completed {done} of {args.episodes} ({len(results) - done} aborted); {sent_total} commands")
    print(
        f"emitter: tick p50 {timing.tick_p50_ms:.3f} ms, jitter p99 {timing.tick_jitter_p99_ms:.3f} ms "
        f"({timing.ticks} ticks), send skew p99 {timing.skew_p99_ms:.3f} ms"
    )
    print(
        f"peer={args.peer} transport={transport} episodes={done}/{args.episodes} lost={lost} "
        f"jitter_p99_ms={timing.tick_jitter_p99_ms:.3f} "
        f"jitter_ratio={timing.tick_jitter_p99_ms / max(bare, 1e-6):.2f} skew_p99_ms={timing.skew_p99_ms:.3f} "
        f"delay_p50_ms={np.median(delays):.2f} "
        f"delay_p99_ms={np.percentile(delays, 99):.2f} rtt_p50_ms={np.median(rtts):.1f} "
        f"rtt_p99_ms={np.percentile(rtts, 99):.1f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
