"""Emitter timing with and without the Foxglove live view serving the deployment.

Trains and exports a tiny shared policy for 3 robots, then deploys it on the hardware twin (mild
profile, 1x, DDS on loopback) twice for `--seconds` each: once plain, once with the live view's
WebSocket server (foxglove-sdk) and a client subscribed to every channel, receiving all of it, in a
process of its own as the Foxglove app is (`--client-in-process` runs it on a thread of the deploying
process instead, which shares that process's interpreter lock with the emitter).
From each recording's /mrl/timing: emitter tick jitter p99 (|period - 20 ms|), send skew p99.
The bare timer loop's jitter in the same run is the limit of this machine.

Last line: ``ratio=<jitter p99 with / without> live_jitter_p99_ms=<..> plain_jitter_p99_ms=<..>
messages_to_client=<n>``.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the test peers (tests/peers) this drives are not an installed package
from deploy_timing import bare_timer_jitter_ms, fleet_file, scenario_file, tiny_policy  # noqa: E402

from pipeline.analysis.timing import TimingFigures, timing_figures  # noqa: E402
from pipeline.policy.runtime import PolicyRuntime  # noqa: E402
from pipeline.record.live import LiveView  # noqa: E402
from pipeline.rollout.deployment import DeployRequest, deploy_policy  # noqa: E402
from pipeline.ros.fleet import load_fleet  # noqa: E402
from tests.peers.foxglove_client import Client  # noqa: E402

MAX_STEPS = 100


def run(
    policy: Path, fleet: Path, seconds: float, out: Path, live: bool, in_process: bool = False
) -> tuple[TimingFigures, int]:
    episodes = max(1, round(seconds / (MAX_STEPS * 0.1)))
    request = DeployRequest(episodes=episodes, seed=0, recording=out, progress=False)
    runtime = PolicyRuntime(policy)
    if not live:
        deploy_policy(runtime, load_fleet(fleet), str(fleet), request)
        return timing_figures(out), 0
    limit = seconds * 4 + 120
    with LiveView(port=0) as view:
        if in_process:
            client = Client(view.url, (), limit=1, timeout_s=limit)
        else:
            app = subprocess.Popen(
                [sys.executable, "-m", "tests.peers.foxglove_client", view.url, str(limit)],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                text=True,
            )
        deploy_policy(runtime, load_fleet(fleet), str(fleet), request, live=view)
    if in_process:
        client.stop()
        return timing_figures(out), client.count
    output, _ = app.communicate(timeout=60)
    found = re.search(r"received=(\d+)", output)
    return timing_figures(out), int(found.group(1)) if found else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="deployment time per condition")
    parser.add_argument(
        "--client-in-process", action="store_true", help="the client on a thread of the deploying process"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        scenario = scenario_file(folder, 3)
        policy = tiny_policy(folder / "p", scenario, MAX_STEPS)
        fleet = fleet_file(folder, scenario, 3, 171)
        bare = bare_timer_jitter_ms(10.0)
        print(f"bare 20 ms timer loop: jitter p99 {bare:.3f} ms (the limit on this machine)")
        plain, _ = run(policy, fleet, args.seconds, folder / "plain.mcap", live=False)
        live, count = run(
            policy, fleet, args.seconds, folder / "live.mcap", live=True, in_process=args.client_in_process
        )
    for name, fig in (("without live view", plain), ("with live view   ", live)):
        print(
            f"{name}: tick p50 {fig.tick_p50_ms:.3f} ms, jitter p99 {fig.tick_jitter_p99_ms:.3f} ms, "
            f"send skew p99 {fig.skew_p99_ms:.3f} ms ({fig.ticks} ticks)"
        )
    where = "on a thread of the deploying process" if args.client_in_process else "in a process of its own"
    print(f"the live client ({where}) received {count} messages")
    ratio = live.tick_jitter_p99_ms / max(plain.tick_jitter_p99_ms, 1e-6)
    print(
        f"ratio={ratio:.2f} live_jitter_p99_ms={live.tick_jitter_p99_ms:.3f} "
        f"plain_jitter_p99_ms={plain.tick_jitter_p99_ms:.3f} messages_to_client={count}"
    )


if __name__ == "__main__":
    main()
