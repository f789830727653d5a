"""Message loss a recording shows against the loss the hardware twin itself made.

Deploys the exported policy (--policy) on the twin with a reality profile drawn from
`pipeline.twin.draw` (seed --profile-seed) for --episodes episodes at --time-scale, counts the messages the
twin dropped on purpose (its own tally, printed when it stops) and calibrates the recording: the calibrated
loss should match the twin's, not exceed it (an excess is loss of our own making: readers, recorder).
Last line: ``twin_loss=<fraction> recorded_loss=<fraction> low=<..> high=<..> ratio=<recorded / twin>``.
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import yaml

import pipeline.rollout.deployment as deployment
from pipeline.calibration import calibrate
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.scenario import load_scenario
from pipeline.policy.runtime import PolicyRuntime
from pipeline.ros.fleet import load_fleet
from pipeline.twin.draw import draw_profile_mapping

STOPPED = re.compile(r"\((\d+) messages sent, (\d+) lost\)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="models/nominal/policy")
    parser.add_argument("--fleet", default="twin")
    parser.add_argument("--profile-seed", type=int, default=108)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--time-scale", type=float, default=3.0)
    args = parser.parse_args()
    tally: dict[str, int] = {}
    stop = deployment.TwinProcess.stop

    def stop_and_read(self: deployment.TwinProcess, timeout_s: float = 5.0) -> None:  # the twin's own tally
        stop(self, timeout_s)
        time.sleep(0.5)
        for line in self.lines:
            if found := STOPPED.search(line):
                tally["sent"], tally["lost"] = int(found.group(1)), int(found.group(2))

    deployment.TwinProcess.stop = stop_and_read  # type: ignore[method-assign]
    runtime = PolicyRuntime(args.policy)
    fleet = load_fleet(args.fleet)
    mapping = draw_profile_mapping(args.profile_seed, len(load_scenario(fleet.scenario).obstacles))
    print(f"profile {args.profile_seed}: network {mapping['network']}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        profile = Path(tmp) / "profile.yaml"
        profile.write_text(yaml.safe_dump(mapping), encoding="utf-8")
        recording = Path(tmp) / "session.mcap"
        request = deployment.DeployRequest(
            episodes=args.episodes,
            seed=20_000,
            recording=recording,
            time_scale=args.time_scale,
            profile=str(profile),
            progress=False,
        )
        deployment.deploy_policy(runtime, fleet, args.fleet, request)
        loss = calibrate(recording, CalibrationSettings(bootstrap=100, seed=0)).values["network.loss_prob"]
    if "lost" not in tally:
        raise SystemExit("twin_loss: the twin did not report its tally")
    twin = tally["lost"] / (tally["sent"] + tally["lost"])
    low, high = loss.interval if loss.interval is not None else (float("nan"), float("nan"))
    value = float(loss.value) if loss.value is not None else float("nan")
    print(f"twin dropped {tally['lost']} of {tally['sent'] + tally['lost']} messages; the recording reads {value:.4f}")
    print(f"twin_loss={twin:.4f} recorded_loss={value:.4f} low={low:.4f} high={high:.4f} ratio={value / twin:.2f}")


if __name__ == "__main__":
    main()
