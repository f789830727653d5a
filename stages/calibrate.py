"""dvc stage `calibrate`: estimate the fleet's lidar, actuation, odometry and network from a deployment
recording, and write the calibration file the calibrated round trains with, plus a fit report."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.calibration import calibrate, calibration_settings, write_calibration
from pipeline.cli import run_stage, stage_arguments
from pipeline.params import load_params


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    cfg = params.calibrate
    settings = calibration_settings(
        {
            "parts": list(cfg.parts),
            "scenario": params.world.scenario,
            "stationary_min_s": cfg.stationary_min_s,
            "bootstrap": cfg.bootstrap,
            "seed": cfg.seed,
        },
        source=f"{args.params} (calibrate)",
    )
    recording = Path(params.deploy.out_dir) / cfg.round / "session.mcap"
    calibration = calibrate([recording], settings)
    path = write_calibration(calibration, cfg.out_dir)
    for key, reason in calibration.unidentified().items():
        print(f"calibrate: {key} unidentifiable: {reason}")
    print(f"calibrate: {path} from {recording}")
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("calibrate", main))
