"""How fast the hardware twin can run before timing breaks: one deployment per time scale.

For each --scales value it deploys the exported policy (by default the nominal round's) on the
twin (--profile, harsh by default) for --episodes episodes with the same seed, and prints from
the recording and the clock on the wall:

- the achieved speed: simulated control time / wall-clock of the session (start-up and resets
  included), and its ratio to the requested scale;
- on the runner's (simulated) clock: tick jitter p99, send skew p99, joint-state age p99 and the
  stale records, i.e. whether the control loop still sees fresh data at every step;
- aborted episodes and robot-level success.

The limit is the requested scale itself. A scale is clean when it aborts nothing and its share of
stale robot-control-steps exceeds that of the lowest scale (the baseline, measured in the same
run) by at most 0.1 %. Last line: ``ratio=<achieved/requested at the largest clean scale>
max_clean_scale=<scale>``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from pipeline.analysis.timing import timing_figures
from pipeline.core.episode import summarize
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet

STALE_MARGIN = 0.001


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=Path("models/nominal/policy"))
    parser.add_argument("--fleet", default="twin")
    parser.add_argument("--profile", default="harsh")
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0, 2.0, 4.0, 8.0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=20000)
    args = parser.parse_args()
    if not (args.policy / "policy.json").is_file():
        print(f"time_scale: no exported policy at {args.policy} (run `dvc repro` first or pass --policy)")
        return 2
    runtime = PolicyRuntime(args.policy)
    fleet = load_fleet(args.fleet)
    clean: tuple[float, float] | None = None
    baseline: float | None = None
    with tempfile.TemporaryDirectory() as tmp:
        for scale in sorted(args.scales):
            recording = Path(tmp) / f"scale{scale:g}.mcap"
            request = DeployRequest(
                episodes=args.episodes,
                seed=args.seed,
                recording=recording,
                time_scale=scale,
                profile=args.profile,
                progress=False,
            )
            start = time.perf_counter()
            results, _ = deploy_policy(runtime, fleet, args.fleet, request)
            wall = time.perf_counter() - start
            t = timing_figures(recording)
            m = summarize(results, prefix="real")
            simulated = t.controls * runtime.spec.world.control_period_s
            achieved = simulated / wall
            aborted = int(m["real/aborted_episodes"])
            print(
                f"scale {scale:4g}: achieved {achieved:5.2f}x ({achieved / scale:.2f} of requested), "
                f"{simulated:.0f} s simulated in {wall:.0f} s; jitter p99 {t.tick_jitter_p99_ms:.2f} ms, "
                f"skew p99 {t.skew_p99_ms:.2f} ms, state age p99 {t.age_p99_ms:.0f} ms, {t.stale} stale records, "
                f"{aborted} aborted, robot success {m.get('real/robot_success', float('nan')):.3f}",
                flush=True,
            )
            stale_share = t.stale / max(t.controls * len(fleet.robots), 1)
            baseline = stale_share if baseline is None else baseline
            if t.stale_examples:
                print(f"           stale: {stale_share:.3%} of robot steps, e.g. {'; '.join(t.stale_examples)}")
            if aborted == 0 and stale_share <= baseline + STALE_MARGIN:
                clean = (scale, achieved / scale)
    if clean is None:
        print("ratio=nan max_clean_scale=none")
    else:
        print(f"ratio={clean[1]:.2f} max_clean_scale={clean[0]:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
